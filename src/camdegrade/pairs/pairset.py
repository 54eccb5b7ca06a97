"""A pair set: the real (clean, captured) pairs that fitting and diagnosis both start from, and the value passed
down between them.

One flow for both workflows: discover the files (:func:`~camdegrade.pairs.discovery.discover_pairs`, the only step
outside this module) → load each pair (:func:`load_pair`: EXIF applied; a file that cannot be decoded is reported
and skipped, never the end of the run) → optionally register each pair (:func:`~camdegrade.pairs.align.align_pair`)
→ split by scene (:meth:`PairSet.split`); a profile then simulates the clean images
(:meth:`~camdegrade.profile.CameraProfile.simulate`). ``fit_profile`` trains on one part of a split and validates on
the other; ``diagnose`` calibrates on one part and measures every gap on the other.
"""

from __future__ import annotations

import os
import random
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from torch import Tensor

from camdegrade._support.pixels import as_unit
from camdegrade.errors import PairsError
from camdegrade.io import read_image
from camdegrade.pairs.align import AlignmentResult, align_pair, format_shifts
from camdegrade.pairs.discovery import discover_pairs
from camdegrade.pairs.pair import UNREADABLE, Pair, PairReport, size_text

#: One aligned pair as tensors: (clean, captured), ``(3, H, W)`` each, same size: uint8 (as read), or float in [0, 1].
ImagePair = tuple[Tensor, Tensor]

__all__ = ["ImagePair", "Log", "PairSet", "PairsSource", "held_out_scenes", "load_pair", "split_by_scene"]

Log = Callable[[str], None]


@dataclass
class PairSet:
    """Loaded (clean, captured) pairs with a scene id and a name each.

    ``images`` keeps what was loaded (uint8 from files; tensors as given); :meth:`unit_pairs` gives float32 in
    [0, 1]. ``report`` is the discovery report (files found and skipped, with reasons) when the set came from files.
    ``shifts`` maps each pair's name to how it was registered (an :class:`~camdegrade.pairs.align.AlignmentResult`)
    once :meth:`aligned`, else ``None``.
    """

    images: list[tuple[Tensor, Tensor]]
    scenes: list[str]
    names: list[str]
    report: PairReport | None = field(default=None, repr=False)
    shifts: dict[str, AlignmentResult] | None = field(default=None, repr=False)

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
        align: bool = False,
        log: Log | None = None,
    ) -> PairSet:
        """Discover and load the pairs of ``source`` (at most ``max_pairs``, the first in name order); files that
        cannot be used are listed in ``report.skipped`` (and in the log) and left out.

        The loading options (``clean_suffix``, ``captured_suffix``, ``strict``, ``size_mismatch``: see
        :func:`~camdegrade.pairs.discovery.discover_pairs`) apply to a path, which is discovered here; a
        :class:`PairReport` was discovered already, and a pair set was loaded already (it is returned as it is, or
        its first ``max_pairs``). ``align`` registers every pair (:meth:`aligned`)."""
        if max_pairs is not None and (isinstance(max_pairs, bool) or not isinstance(max_pairs, int) or max_pairs < 1):
            raise ValueError(f"max_pairs must be a positive integer or None, got max_pairs={max_pairs!r}")
        if isinstance(source, PairSet):
            pair_set = source if max_pairs is None else source.subset(range(min(max_pairs, len(source))))
            return pair_set.aligned(log) if align and pair_set.shifts is None else pair_set
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
        return pair_set.aligned(log) if align else pair_set

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

    def subset(self, indices: Iterable[int]) -> PairSet:
        """The pairs at ``indices``, in that order (the report is not carried over; their shifts are)."""
        indices = list(indices)
        names = [self.names[i] for i in indices]
        shifts = None if self.shifts is None else {name: self.shifts[name] for name in names}
        return PairSet([self.images[i] for i in indices], [self.scenes[i] for i in indices], names, shifts=shifts)

    def split(self, holdout: float, seed: int) -> tuple[PairSet, PairSet]:
        """``(rest, held_out)``: a share ``holdout`` of the scenes (seeded) held out; no scene on both sides."""
        chosen = held_out_scenes(self.scenes, holdout, seed)
        held = [i for i, scene in enumerate(self.scenes) if scene in chosen]
        rest = [i for i, scene in enumerate(self.scenes) if scene not in chosen]
        return self.subset(rest), self.subset(held)

    def validation_split(self, val_fraction: float, seed: int) -> tuple[PairSet, PairSet]:
        """``(train, validation)``: a share ``val_fraction`` of the scenes (seeded) validates, as :meth:`split`;
        everything trains (the validation part is empty) with one scene or ``val_fraction`` 0."""
        if val_fraction == 0 or len(set(self.scenes)) < 2:
            return self, self.subset([])
        return self.split(val_fraction, seed)

    def aligned(self, log: Log | None = None) -> PairSet:
        """Every pair registered (sub-pixel translation, clean moved onto the capture) and cropped to its overlap."""
        images, shifts = [], {}
        for name, (clean, captured) in zip(self.names, self.images, strict=True):
            clean, captured, shifts[name] = align_pair(clean, captured)
            images.append((clean, captured))
        if log is not None and shifts:
            log(format_shifts(shifts))
        return PairSet(images, list(self.scenes), list(self.names), self.report, shifts)

    def unit_pairs(self) -> list[tuple[Tensor, Tensor]]:
        """The pairs as float32 ``(3, H, W)`` in [0, 1]."""
        return [(as_unit(clean, clamp=True), as_unit(captured, clamp=True)) for clean, captured in self.images]

    def cleans(self) -> list[Tensor]:
        return [as_unit(clean, clamp=True) for clean, _ in self.images]

    def captured(self) -> list[Tensor]:
        return [as_unit(captured, clamp=True) for _, captured in self.images]


#: What a pair set can be made from: a folder or CSV manifest (see ``discover_pairs``), a discovery report, a list
#: of file pairs, a list of ``(clean, captured)`` tensors ``(3, H, W)`` (uint8, or float in [0, 1]), or a pair set.
PairsSource = str | os.PathLike[str] | PairReport | Sequence[Pair] | Sequence[tuple[Tensor, Tensor]] | PairSet


def load_pair(pair: Pair) -> tuple[Tensor, Tensor]:
    """Read both images of ``pair`` as uint8 ``(3, H, W)`` tensors (EXIF orientation applied).

    Raises:
        PairsError: the two images differ in size (and the pair was not marked for cropping).
        OSError, ValueError: an image cannot be read (see :func:`camdegrade.io.read_image`).
    """
    clean, captured = read_image(pair.clean), read_image(pair.captured)
    if pair.crop_to is not None:
        clean, captured = (
            _centre_crop(clean, pair.crop_to, pair.clean),
            _centre_crop(captured, pair.crop_to, pair.captured),
        )
    if clean.shape != captured.shape:
        raise PairsError(
            f"pair {pair.name!r}: clean image is {size_text(clean.shape[-2:])} but captured image is "
            f"{size_text(captured.shape[-2:])} ({pair.clean} vs {pair.captured}); use size_mismatch='crop' "
            "to centre-crop both to the common size"
        )
    return clean, captured


def split_by_scene(
    pairs: Sequence[Pair], holdout: Iterable[str] | float, seed: int = 0
) -> tuple[list[Pair], list[Pair]]:
    """Split file pairs (before loading them) into (train, held_out) so that no scene appears on both sides.

    Args:
        pairs: the pairs to split; each side keeps their order.
        holdout: scene ids to hold out, a fraction of the scenes in (0, 1), or a number of scenes (int).
        seed: seeds the choice of scenes when ``holdout`` is a fraction or a count.
    """
    chosen = held_out_scenes([pair.scene for pair in pairs], holdout, seed)
    train = [pair for pair in pairs if pair.scene not in chosen]
    held_out = [pair for pair in pairs if pair.scene in chosen]
    return train, held_out


def held_out_scenes(scenes: Iterable[str], holdout: Iterable[str] | float, seed: int = 0) -> set[str]:
    """The scenes :func:`split_by_scene` holds out of ``scenes`` (ids, a fraction or a count, seeded)."""
    known = sorted(set(scenes))
    if isinstance(holdout, bool):
        raise PairsError(f"holdout must be scene ids, a fraction or a count, got holdout={holdout!r}")
    if isinstance(holdout, (int, float)):
        return _draw_scenes(known, holdout, seed)
    chosen = {holdout} if isinstance(holdout, str) else set(holdout)
    unknown = sorted(chosen - set(known))
    if unknown:
        raise PairsError(f"holdout names scenes that no pair has: {unknown[:10]}; known scenes include {known[:10]}")
    return chosen


def _draw_scenes(scenes: list[str], holdout: float, seed: int) -> set[str]:
    if isinstance(holdout, float):
        if not 0.0 < holdout < 1.0:
            raise PairsError(f"holdout as a fraction must be between 0 and 1 (exclusive), got holdout={holdout}")
        count = max(1, round(holdout * len(scenes)))
    else:
        count = holdout
    if not 1 <= count < len(scenes):
        raise PairsError(
            f"holding out {count} of {len(scenes)} scenes leaves no scene on one side; "
            "need at least 2 scenes and a holdout smaller than their number"
        )
    return set(random.Random(seed).sample(scenes, count))


def _centre_crop(image: Tensor, size: tuple[int, int], path: Path) -> Tensor:
    height, width = size
    if image.shape[-2] < height or image.shape[-1] < width:
        raise PairsError(f"{path} is {size_text(image.shape[-2:])}, smaller than the crop {size_text(size)}")
    top = (image.shape[-2] - height) // 2
    left = (image.shape[-1] - width) // 2
    return image[..., top : top + height, left : left + width]
