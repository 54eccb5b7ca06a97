"""The unpaired fit's checkpoint: what its finished steps left, written after every step, so that an interrupted fit
(Ctrl-C, a killed process) resumes at the next step and ends with the profile an uninterrupted fit gives.

The file is a camdegrade profile (:meth:`~camdegrade.CameraProfile.save`, read back by
:func:`~camdegrade.profile.load_profile`: safetensors, written atomically, read strictly, never unpickled): its
effects are the stages kept so far and ``fitted[CHECKPOINT_KEY]`` holds the rest of the fit's state (each finished
step's record, the warnings, why stages were not fitted), how many steps are done, the seconds spent, and a
fingerprint of everything the steps depend on (:func:`fit_fingerprint`). Nothing else carries from one step to the
next: what the steps need of the sets (:class:`~camdegrade.fitting.unpaired.bench.Measured`) is measured again from
the same images, and each step draws its randomness from the seed alone."""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from camdegrade._profile_format.effect_facts import short_repr
from camdegrade._profile_format.header import FORMAT_VERSION
from camdegrade._version import __version__
from camdegrade.effects import Effect
from camdegrade.errors import CheckpointError, ProfileError
from camdegrade.fitting.unpaired.bench import UnpairedFit, UnpairedStep
from camdegrade.fitting.unpaired.images import ImageSet
from camdegrade.profile import CameraProfile, load_profile

__all__ = ["CHECKPOINT_KEY", "CHECKPOINT_VERSION", "StepCheckpoint", "check_checkpoint", "fit_fingerprint"]

#: The key of ``fitted`` that marks a profile file as an unpaired fit's checkpoint and holds its state.
CHECKPOINT_KEY = "unpaired_checkpoint"
#: The layout of that state; a checkpoint of another layout is refused.
CHECKPOINT_VERSION = 1
_DESCRIPTION = "an unfinished unpaired fit (camdegrade fit --unpaired ... --resume continues it)"
_START_AFRESH = "start a new fit without resume"


def check_checkpoint(checkpoint: str | os.PathLike[str] | None, resume: bool) -> Path | None:
    """``checkpoint`` as a path, checked before any work: a ``.safetensors`` path, and an existing file for
    ``resume`` (which needs one)."""
    if not isinstance(resume, bool):
        raise TypeError(f"resume must be a bool, got resume={resume!r}")
    if checkpoint is None:
        if resume:
            raise ValueError("resume=True needs checkpoint=PATH: the file an earlier fit wrote after each step")
        return None
    if not isinstance(checkpoint, (str, os.PathLike)):
        raise TypeError(f"checkpoint must be a path, got checkpoint={checkpoint!r} ({type(checkpoint).__name__})")
    path = Path(checkpoint)
    if path.suffix != ".safetensors":
        raise ValueError(f"checkpoint must end in '.safetensors', got checkpoint={str(path)!r}")
    if resume and not path.is_file():
        raise FileNotFoundError(f"resume: checkpoint {str(path)!r} does not exist; check its path, or {_START_AFRESH}")
    return path


def fit_fingerprint(
    captures: ImageSet,
    cleans: ImageSet | None,
    steps: Sequence[tuple[str, UnpairedStep]],
    *,
    wanted: Sequence[str],
    seed: int,
    sensor_scale: float | str,
    max_images: int | None,
) -> dict[str, Any]:
    """What an unpaired fit's result depends on, in parts a refusal can name: a hash of each side's images (every
    pixel, size, JPEG tables and the files skipped) and the options (the stages asked for, the seed,
    ``sensor_scale``, ``max_images``, the steps with their options, the profile format and package versions)."""
    return {
        "captured": _images_hash(captures),
        "clean": None if cleans is None else _images_hash(cleans),
        "options": {
            "effects": list(wanted),
            "seed": seed,
            "sensor_scale": sensor_scale,
            "max_images": max_images,
            "steps": [f"{label}: {step!r}" for label, step in steps],
            "format_version": FORMAT_VERSION,
            "package_version": __version__,
        },
    }


def _images_hash(images: ImageSet) -> str:
    digest = hashlib.blake2b(digest_size=16)
    listing = {"count": len(images.images), "tables": images.tables, "skipped": images.skipped}
    digest.update(json.dumps(listing, sort_keys=True).encode())
    for image in images.images:
        digest.update(f"{tuple(image.shape)} {image.dtype};".encode())
        digest.update(image.detach().cpu().contiguous().numpy().tobytes())
    return digest.hexdigest()


@dataclass
class StepCheckpoint:
    """Where an unpaired fit writes its progress (``path``; ``None``: nowhere), the fingerprint it must match, the
    steps' labels, and how far the fit is: ``done`` steps, ``seconds`` spent by earlier runs."""

    path: Path | None
    fingerprint: dict[str, Any]
    labels: list[str]
    done: int = 0
    seconds: float = 0.0
    _loaded: tuple[list[Effect], dict[str, Any]] | None = field(default=None, repr=False)

    @property
    def total(self) -> int:
        return len(self.labels)

    def save(self, fit: UnpairedFit, done: int, seconds: float) -> None:
        """The fit after ``done`` steps, ``seconds`` into it (all runs), written atomically over the last one (``done``
        counts once the file is whole: an interrupted write leaves the last one and its count)."""
        if self.path is None:
            self.done = done
            return
        state = {
            "version": CHECKPOINT_VERSION,
            "fingerprint": self.fingerprint,
            "steps_done": done,
            "steps": self.total,
            "records": fit.records,
            "not_fitted": fit.not_fitted,
            "warnings": fit.warnings,
            "seconds": round(seconds, 3),
        }
        profile = CameraProfile(None, fit.chain(), name="unpaired checkpoint", description=_DESCRIPTION)
        profile.fitted = {CHECKPOINT_KEY: state}
        profile.save(self.path)
        self.done = done

    def read(self) -> None:
        """Read the checkpoint at ``path``, before the fit measures its sets: an unpaired fit's checkpoint written for
        the same images and options, else a :class:`CheckpointError` naming the file and what differs."""
        path = str(self.path)
        stages, state = _read(path)
        _check_fingerprint(path, state["fingerprint"], self.fingerprint)
        if not 0 <= state["steps_done"] <= self.total or state["steps"] != self.total:
            raise CheckpointError(
                f"checkpoint {path!r} counts {state['steps_done']} of {state['steps']} steps done, this fit has "
                f"{self.total}; {_START_AFRESH}"
            )
        self._loaded = (stages, state)

    def restore(self, fit: UnpairedFit) -> float:
        """``fit`` as the checkpoint :meth:`read` left it (stages, records, reasons, warnings); the seconds the earlier
        runs spent."""
        if self._loaded is None:
            self.read()
        stages, state = self._loaded
        fit.stages = {stage.name: stage for stage in stages}
        fit.records, fit.not_fitted = state["records"], state["not_fitted"]
        fit.warnings = list(state["warnings"])
        self.done, self.seconds = state["steps_done"], float(state["seconds"])
        after = f" ({self.labels[self.done - 1]})" if self.done else ""
        fit.say(f"unpaired fit: resumed from {str(self.path)!r} after step {self.done} of {self.total}{after}")
        return self.seconds

    def interrupted(self) -> str:
        """What an interruption during the step after the ``done`` ones leaves: which step, and the file."""
        return (
            f"unpaired fit interrupted during step {self.done + 1} of {self.total} ({self.labels[self.done]}); "
            f"checkpoint {str(self.path)!r} holds the {self.done} steps before it"
        )


#: The state's entries and the JSON type each must have.
_STATE_TYPES: dict[str, type | tuple[type, ...]] = {
    "version": int,
    "fingerprint": dict,
    "steps_done": int,
    "steps": int,
    "records": dict,
    "not_fitted": dict,
    "warnings": list,
    "seconds": (int, float),
}


def _read(path: str) -> tuple[list[Effect], dict[str, Any]]:
    """The stages and the state of the checkpoint at ``path``, each entry of the state of its type."""
    not_ours = f"checkpoint {path!r} is not a camdegrade unpaired fit's checkpoint"
    try:
        profile = load_profile(path)
    except ProfileError as error:
        raise CheckpointError(f"{not_ours} ({error}); {_START_AFRESH}") from None
    state = profile.fitted.get(CHECKPOINT_KEY)
    if not isinstance(state, dict):
        raise CheckpointError(f"{not_ours} (a profile without {CHECKPOINT_KEY!r} in 'fitted'); {_START_AFRESH}")
    if state.get("version") != CHECKPOINT_VERSION:
        raise CheckpointError(
            f"{not_ours} of layout version {CHECKPOINT_VERSION} (found {state.get('version')!r}: another camdegrade "
            f"version wrote it); {_START_AFRESH}"
        )
    for key, kind in _STATE_TYPES.items():
        value = state.get(key)
        if not isinstance(value, kind) or isinstance(value, bool) or not _finite(value):
            raise CheckpointError(f"{not_ours} (damaged: {key!r} is {short_repr(value)}); {_START_AFRESH}")
    if not all(isinstance(warning, str) for warning in state["warnings"]):
        raise CheckpointError(f"{not_ours} (damaged: 'warnings' holds more than text); {_START_AFRESH}")
    return list(profile.effects), state


def _finite(value: Any) -> bool:
    return not isinstance(value, float) or math.isfinite(value)


def _check_fingerprint(path: str, saved: dict[str, Any], now: dict[str, Any]) -> None:
    """A :class:`CheckpointError` naming the first part of the fingerprint that differs: a side's images, or the
    options with the saved and the current values."""
    for side, argument in (("captured", "captured (CAPTURED)"), ("clean", "clean (--clean)")):
        if saved.get(side) != now[side]:
            raise CheckpointError(
                f"resume: checkpoint {path!r} was written for other {argument} images (images, files or their order "
                f"differ); resume with the same images, or {_START_AFRESH}"
            )
    saved_options = saved.get("options") if isinstance(saved.get("options"), dict) else {}
    for key, value in now["options"].items():
        if key == "steps" and saved_options.get(key) != value:
            raise CheckpointError(
                f"resume: checkpoint {path!r} was written by a fit of other steps or step options (another "
                f"camdegrade version); resume with the same options, or {_START_AFRESH}"
            )
        if saved_options.get(key) != value:
            raise CheckpointError(
                f"resume: checkpoint {path!r} was written with {key}={saved_options.get(key)!r}, this fit has "
                f"{key}={value!r}; resume with the same options, or {_START_AFRESH}"
            )
