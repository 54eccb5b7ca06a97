"""A pair set: the real (clean, captured) pairs that fitting and diagnosis both start from.

One flow for both workflows: discover the files (:func:`~camdegrade.fitting.pairs.discover_pairs`) → load each
pair (EXIF applied; a file that cannot be decoded is reported and skipped, never the end of the run) → split by
scene → optionally register each pair (:func:`~camdegrade.fitting.align.align_pair`) → simulate the clean images
with a profile, each image seeded from ``(seed, stream, index)``. ``fit_profile`` trains on one part of a split and
validates on the other; ``diagnose`` calibrates on one part and measures every gap on the other.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import torch
from torch import Tensor

from camdegrade._pixels import as_unit
from camdegrade._seeds import derived_generator
from camdegrade.errors import PairsError
from camdegrade.fitting.align import align_pair, format_shifts
from camdegrade.fitting.pairs import UNREADABLE, Pair, PairReport, discover_pairs, held_out_scenes, load_pair
from camdegrade.profile import CameraProfile

#: What a pair set can be made from: a folder or CSV manifest (see ``discover_pairs``), a discovery report, a list
#: of file pairs, or a list of ``(clean, captured)`` tensors ``(3, H, W)`` (uint8, or float in [0, 1]).
PairsSource = str | os.PathLike[str] | PairReport | Sequence[Pair] | Sequence[tuple[Tensor, Tensor]]
Log = Callable[[str], None]


@dataclass
class PairSet:
    """Loaded (clean, captured) pairs with a scene id and a name each.

    ``images`` keeps what was loaded (uint8 from files; tensors as given); :meth:`unit_pairs` gives float32 in
    [0, 1]. ``report`` is the discovery report (files found and skipped, with reasons) when the set came from files.
    """

    images: list[tuple[Tensor, Tensor]]
    scenes: list[str]
    names: list[str]
    report: PairReport | None = field(default=None, repr=False)

    @classmethod
    def load(
        cls,
        source: PairsSource,
        *,
        clean_suffix: str | None = None,
        captured_suffix: str | None = None,
        strict: bool = False,
        size_mismatch: Literal["skip", "crop"] = "skip",
        max_pairs: int | None = None,
        log: Log | None = None,
    ) -> PairSet:
        """Discover and load the pairs of ``source`` (at most ``max_pairs``, the first in name order); files that
        cannot be used are listed in ``report.skipped`` (and in the log) and left out."""
        if max_pairs is not None and (isinstance(max_pairs, bool) or not isinstance(max_pairs, int) or max_pairs < 1):
            raise ValueError(f"max_pairs must be a positive integer or None, got max_pairs={max_pairs!r}")
        if isinstance(source, (str, os.PathLike)):
            source = discover_pairs(
                Path(source),
                clean_suffix=clean_suffix,
                captured_suffix=captured_suffix,
                strict=strict,
                size_mismatch=size_mismatch,
            )
        if isinstance(source, PairReport):
            pair_set = cls._from_files(source, max_pairs)
        else:
            pair_set = cls._from_items(list(source)[:max_pairs])
        if log is not None and pair_set.report is not None:
            log(pair_set.report.summary())
        return pair_set

    @classmethod
    def _from_files(cls, report: PairReport, max_pairs: int | None) -> PairSet:
        skipped = list(report.skipped)
        images, scenes, names = [], [], []
        for pair in report.pairs[:max_pairs]:
            try:
                images.append(load_pair(pair))
            except (OSError, PairsError) as error:  # a header that reads but data that does not decode
                skipped.append((pair.captured, f"{UNREADABLE}: {error}"))
                continue
            scenes.append(pair.scene)
            names.append(pair.name)
        loaded = set(names)
        kept = [pair for pair in report.pairs if pair.name in loaded]
        final = PairReport(pairs=kept, skipped=skipped, source=report.source, layout=report.layout)
        if not images:
            raise PairsError(f"no pair could be loaded.\n{final.summary()}")
        return cls(images, scenes, names, final)

    @classmethod
    def _from_items(cls, items: list) -> PairSet:
        if not items:
            raise PairsError("pairs must hold at least one (clean, captured) pair, got none")
        if all(isinstance(item, Pair) for item in items):
            return cls._from_files(PairReport(pairs=items, skipped=[]), None)
        if not all(isinstance(item, (tuple, list)) and len(item) == 2 for item in items):
            raise TypeError(
                "pairs must be a folder or CSV path, a PairReport, a list of Pair or a list of (clean, captured) "
                f"tensors, got a list of {sorted({type(item).__name__ for item in items})}"
            )
        images = []
        for index, (clean, captured) in enumerate(items):
            if not (isinstance(clean, Tensor) and isinstance(captured, Tensor)):
                raise TypeError(f"pair {index}: clean and captured must be tensors, got {type(clean).__name__}")
            if clean.ndim != 3 or clean.shape[0] != 3 or clean.shape != captured.shape:
                raise ValueError(
                    f"pair {index}: clean and captured must be (3, H, W) of the same size, "
                    f"got {tuple(clean.shape)} and {tuple(captured.shape)}"
                )
            images.append((clean, captured))
        names = [str(index) for index in range(len(images))]
        return cls(images, list(names), names)

    def __len__(self) -> int:
        return len(self.images)

    def subset(self, indices: Sequence[int]) -> PairSet:
        """The pairs at ``indices``, in that order (the report is not carried over)."""
        return PairSet(
            [self.images[i] for i in indices], [self.scenes[i] for i in indices], [self.names[i] for i in indices]
        )

    def split(self, holdout: float, seed: int) -> tuple[PairSet, PairSet]:
        """``(rest, held_out)``: a share ``holdout`` of the scenes (seeded) held out; no scene on both sides."""
        chosen = held_out_scenes(self.scenes, holdout, seed)
        held = [i for i, scene in enumerate(self.scenes) if scene in chosen]
        rest = [i for i, scene in enumerate(self.scenes) if scene not in chosen]
        return self.subset(rest), self.subset(held)

    def aligned(self, log: Log | None = None) -> PairSet:
        """Every pair registered (sub-pixel translation, clean moved onto the capture) and cropped to its overlap."""
        images, shifts = [], {}
        for name, (clean, captured) in zip(self.names, self.images, strict=True):
            clean, captured, shifts[name] = align_pair(clean, captured)
            images.append((clean, captured))
        if log is not None and shifts:
            log(format_shifts(shifts))
        return PairSet(images, list(self.scenes), list(self.names), self.report)

    def unit_pairs(self) -> list[tuple[Tensor, Tensor]]:
        """The pairs as float32 ``(3, H, W)`` in [0, 1]."""
        return [(as_unit(clean, clamp=True), as_unit(captured, clamp=True)) for clean, captured in self.images]

    def cleans(self) -> list[Tensor]:
        return [as_unit(clean, clamp=True) for clean, _ in self.images]

    def captured(self) -> list[Tensor]:
        return [as_unit(captured, clamp=True) for _, captured in self.images]


def simulate(
    profile: CameraProfile,
    cleans: Sequence[Tensor],
    seed: int,
    *,
    stream: str = "simulate",
    deterministic: bool = False,
) -> list[Tensor]:
    """The profile applied to each clean image ``(3, H, W)``; image ``i`` draws from ``(seed, stream, i)``.

    ``deterministic`` runs the profile's deterministic part (:meth:`CameraProfile.without_randomness`): the
    conditional mean that candidate effects are fitted against.
    """
    if deterministic:
        profile = profile.without_randomness()
    out = []
    with torch.no_grad():
        for index, clean in enumerate(cleans):
            batch = clean[None]
            params = profile.make_params(batch.shape, derived_generator(seed, stream, index))
            out.append(profile(batch, params)[0])
    return out
