"""What the foreign-camera benches share (``bench_foreign_fit.py``, ``bench_foreign_diagnosis.py``): the pairs a
foreign camera (``tests/foreign_cameras``, written without camdegrade) makes of clean scenes, and the default fit of
a camera, kept on disk so that the diagnosis bench diagnoses the very profile the fit bench measured.

Content: the fit trains on crops of one set of scikit-image photos (:data:`TRAIN_PHOTOS`) and is measured, and the
diagnosis run, on crops of the others (:data:`OTHER_PHOTOS`), with flat walls and dead-leaves texture drawn from
other seeds.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

REPOSITORY = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPOSITORY / "tests"))

from camdegrade import FitConfig, fit_profile, load_profile  # noqa: E402
from camdegrade.effects import LearnedTexture  # noqa: E402
from camdegrade.fitting.steps.learned import LearnedTexturePaired  # noqa: E402
from camdegrade.profile import CameraProfile  # noqa: E402
from foreign_cameras import Camera, camera, scenes  # noqa: E402

TRAIN_PHOTOS = ("astronaut", "coffee", "rocket", "immunohistochemistry", "brick", "grass", "retina")
OTHER_PHOTOS = ("chelsea", "hubble_deep_field", "colorwheel", "gravel", "camera")
#: Scene seeds: the fit's training pairs, the held-out pairs it is measured on, and the diagnosis pairs.
TRAIN_SEED, HELD_OUT_SEED, DIAGNOSIS_SEED = 101, 202, 303
DEFAULT_OUT = Path("/tmp/foreign")

Pairs = list[tuple[Tensor, Tensor]]


def to_tensor(image: np.ndarray) -> Tensor:
    """uint8 (H, W, 3) → uint8 (3, H, W)."""
    return torch.from_numpy(np.ascontiguousarray(image.transpose(2, 0, 1)))


def make_pairs(chain: Camera, count: int, size: int, scene_seed: int, photos: tuple[str, ...]) -> Pairs:
    """``count`` (clean, captured) uint8 tensor pairs of ``size``²: the scenes of ``scene_seed``, each captured with
    the seed (``scene_seed``, its index), so two chains see the same scenes with the same random draws."""
    cleans = scenes(count, size, seed=scene_seed, photos=photos)
    return [(to_tensor(clean), to_tensor(chain(clean, seed=(scene_seed, index)))) for index, clean in enumerate(cleans)]


def train_pairs(name: str, count: int, size: int) -> Pairs:
    return make_pairs(camera(name), count, size, TRAIN_SEED, TRAIN_PHOTOS)


def held_out_pairs(chain: Camera, count: int, size: int) -> Pairs:
    return make_pairs(chain, count, size, HELD_OUT_SEED, OTHER_PHOTOS)


#: Profiles fitted in this process, by (camera, pairs, size, learned texture): a fit whose profile cannot be saved is
#: still reused.
_FITTED: dict[tuple[str, int, int, str | None], tuple[CameraProfile, dict]] = {}


@dataclass(frozen=True)
class _StageKeptAside(LearnedTexturePaired):
    """The paired fit's learned texture step, its trained stage also put in :data:`_TRAINED` whatever its gate says
    (the bench measures it held out ungated too)."""

    def judge(self, fit: Any, proposal: tuple[LearnedTexture, dict]) -> dict[str, Any]:
        _TRAINED.append(proposal[0])
        return super().judge(fit, proposal)


_TRAINED: list[LearnedTexture] = []


def _recipe(learned_texture: str | None) -> FitConfig:
    """The default recipe, with the learned texture option where asked (its step keeping its stage aside)."""
    config = FitConfig.recipe("fast", learned_texture=learned_texture)
    steps = tuple(_StageKeptAside() if isinstance(s, LearnedTexturePaired) else s for s in config.steps)
    return config.replace(steps=steps)


def _save_ungated(profile: CameraProfile, path: Path, record: dict[str, Any]) -> None:
    """``profile`` with the stage its learned step trained (kept by the gate or not) saved to ``path``."""
    stage = _TRAINED.pop()
    kept = any(isinstance(effect, LearnedTexture) for effect in profile.effects)
    (profile if kept else profile.with_effects(stage)).save(path)
    record["ungated"] = path.name


def fitted_profile(
    name: str, count: int, size: int, out: Path, log: Any = None, learned_texture: str | None = None
) -> tuple[CameraProfile, dict]:
    """The default fit (``fit_profile(pairs)``: the default recipe, one thread) of camera ``name`` on ``count``
    training pairs of ``size``², and a record of how it was made (pairs, size, seconds wall and CPU). Fitted once per
    process, saved to ``out/fits/`` and loaded from there by later processes. A profile that ``CameraProfile.save``
    refuses is kept in this process only, and the refusal is recorded (``save_error``): the fit's output, as a user
    of ``camdegrade fit`` would meet it. ``learned_texture`` (``"critic"``): the default recipe with that option
    (``fit --learned-texture critic``), kept under its own file name (``CAMERA-PAIRSxSIZE-critic``); the profile
    with the stage it trained, whether its gate kept it or not, beside it (``...-critic-ungated``, named in the
    record's ``ungated``)."""
    key = (name, count, size, learned_texture)
    if key in _FITTED:
        return _FITTED[key]
    folder = out / "fits"
    stem = f"{name}-{count}x{size}" + (f"-{learned_texture}" if learned_texture else "")
    path, record_path = folder / f"{stem}.safetensors", folder / f"{stem}.json"
    if path.is_file() and record_path.is_file():
        _FITTED[key] = load_profile(path), json.loads(record_path.read_text())
        return _FITTED[key]
    pairs = train_pairs(name, count, size)
    recipe = _recipe(learned_texture)
    started, cpu_started = time.perf_counter(), time.process_time()
    profile = fit_profile(pairs, recipe, threads=1, name=f"foreign-{name}", log=log)
    record: dict[str, Any] = {"camera": name, "pairs": count, "size": size}
    record["seconds"] = round(time.perf_counter() - started, 1)
    record["cpu_seconds"] = round(time.process_time() - cpu_started, 1)
    if learned_texture:
        record["learned_texture"] = learned_texture
    folder.mkdir(parents=True, exist_ok=True)
    try:
        profile.save(path)
        if _TRAINED:
            _save_ungated(profile, folder / f"{stem}-ungated.safetensors", record)
    except ValueError as error:
        record["save_error"] = str(error)
    record_path.write_text(json.dumps(record, indent=2) + "\n")
    _FITTED[key] = profile, record
    return _FITTED[key]


def stages_of(profile: CameraProfile) -> list[str]:
    """The profile's network architecture (if any) and its stage names, in chain order."""
    network = [f"network ({profile.network.arch})"] if profile.network is not None else []
    return network + [effect.name for effect in profile.effects]
