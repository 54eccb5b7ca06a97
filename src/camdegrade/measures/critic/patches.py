"""The critic's inputs: patches of (clean, real, simulated) pairs cut at the same positions, with where each lies
and what its clean patch holds (see :mod:`camdegrade.measures.critic.core` for the test they feed)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace

import torch
from torch import Tensor

from camdegrade._support.seeds import derived_generator
from camdegrade.functional.analysis.images import box_mean, flat_mask, gradient_energy

__all__ = [
    "FLAT_SHARE",
    "GRID",
    "IMAGE_ONLY_PLANES",
    "PATCH",
    "PATCHES_PER_PAIR",
    "PLANES",
    "PairFeatures",
    "Patches",
    "pair_features",
]

#: The side of a patch, and the grid its corners are drawn on.
PATCH = 32
GRID = 8
#: Patches drawn from each pair (the same positions for its real and its simulated image).
PATCHES_PER_PAIR = 24
#: A patch counts as flat when at least this share of its pixels is.
FLAT_SHARE = 0.5
#: Input planes: clean RGB, residual RGB (image − clean), the image's fine detail RGB (image minus its 3×3
#: mean, where noise and blocking live), and the position (y, x) in the frame.
PLANES = 11
#: Input planes of the image-only critic: the image's RGB and its fine detail RGB.
IMAGE_ONLY_PLANES = 6


@dataclass
class Patches:
    """Critic inputs ``(M, PLANES or IMAGE_ONLY_PLANES, PATCH, PATCH)``, labels (1 real), the pair each came from,
    and its attributes: where it lies (``top``, ``left`` in pixels, ``radius``) and what its clean patch holds
    (``intensity``, ``flat``, ``texture``: mean gradient energy, ``saturation``: mean of max − min over RGB).
    A position's real and simulated patches share every attribute."""

    inputs: Tensor
    labels: Tensor
    pair: Tensor
    radius: Tensor
    intensity: Tensor
    flat: Tensor
    top: Tensor
    left: Tensor
    texture: Tensor
    saturation: Tensor

    @classmethod
    def sample(
        cls,
        cleans: Sequence[Tensor],
        reals: Sequence[Tensor],
        sims: Sequence[Tensor],
        seed: int,
        stream: str,
        image_only: bool = False,
        features: Sequence[PairFeatures | None] | None = None,
    ) -> Patches:
        """:data:`PATCHES_PER_PAIR` positions of each pair (seeded by ``(seed, stream, index)``); ``features``: the
        pairs' :func:`pair_features`, when the caller computed them once for several samples."""
        features = features if features is not None else [None] * len(cleans)
        parts = [
            _pair_patches(index, clean, real, sim, derived_generator(seed, stream, index), image_only, feature)
            for index, (clean, real, sim, feature) in enumerate(zip(cleans, reals, sims, features, strict=True))
        ]
        parts = [part for part in parts if part is not None]
        if not parts:
            raise ValueError(f"the critic needs pairs of at least {PATCH}x{PATCH} pixels")
        return cls(*(torch.cat(column) for column in zip(*parts, strict=True)))

    def __len__(self) -> int:
        return self.labels.numel()

    @classmethod
    def concat(cls, parts: Sequence[Patches]) -> Patches:
        """The patches of ``parts`` in order, the pairs of each numbered after those of the parts before it."""
        offset, shifted = 0, []
        for part in parts:
            shifted.append(replace(part, pair=part.pair + offset))
            offset += int(part.pair.max()) + 1 if len(part) else 0
        return cls(*(torch.cat([getattr(part, f.name) for part in shifted]) for f in fields(cls)))


@dataclass
class PairFeatures:
    """What the patches of one (clean, real, sim) pair are cut from, whatever their positions: the flat mask, the
    gradient energy and the colourfulness of the clean image, and the fine detail of the real and the simulated
    image (each minus its 3×3 mean)."""

    flat: Tensor
    energy: Tensor
    chroma: Tensor
    detail: dict[float, Tensor]


def pair_features(clean: Tensor, real: Tensor, sim: Tensor) -> PairFeatures:
    """:class:`PairFeatures` of one pair (computed once, they serve every critic that samples it)."""
    return PairFeatures(
        flat=flat_mask(clean).float(),
        energy=gradient_energy(clean),
        chroma=clean.amax(-3) - clean.amin(-3),
        detail={label: image - box_mean(image, 3) for label, image in ((1.0, real), (0.0, sim))},
    )


def _pair_patches(
    index: int,
    clean: Tensor,
    real: Tensor,
    sim: Tensor,
    generator: torch.Generator,
    image_only: bool = False,
    features: PairFeatures | None = None,
) -> tuple[Tensor, ...] | None:
    height, width = clean.shape[-2:]
    if min(height, width) < PATCH:
        return None
    # On the 8-pixel grid: a codec's 8×8 blocks and the network's 4-pixel grid keep one phase in every patch.
    tops = (torch.randint(0, (height - PATCH) // GRID + 1, (PATCHES_PER_PAIR,), generator=generator) * GRID).tolist()
    lefts = (torch.randint(0, (width - PATCH) // GRID + 1, (PATCHES_PER_PAIR,), generator=generator) * GRID).tolist()
    ys = torch.linspace(-1, 1, height)[:, None].expand(height, width)
    xs = torch.linspace(-1, 1, width)[None, :].expand(height, width)
    features = features or pair_features(clean, real, sim)
    flat, energy, chroma, detail = features.flat, features.energy, features.chroma, features.detail
    inputs, labels, radius, intensity, flat_share, texture, saturation = [], [], [], [], [], [], []
    for top, left in zip(tops, lefts, strict=True):
        window = (..., slice(top, top + PATCH), slice(left, left + PATCH))
        position = torch.stack([ys[window], xs[window]])
        for label, image in ((1.0, real), (0.0, sim)):
            if image_only:
                inputs.append(torch.cat([image[window], detail[label][window]]))
            else:
                residual = image[window] - clean[window]
                inputs.append(torch.cat([clean[window], residual, detail[label][window], position]))
            labels.append(label)
        centre_y, centre_x = (top + PATCH / 2) / height - 0.5, (left + PATCH / 2) / width - 0.5
        patch_radius = math.hypot(centre_y, centre_x) / math.hypot(0.5, 0.5)
        patch_intensity = float(clean[window].mean())
        share = float(flat[window].mean())
        radius += [patch_radius] * 2
        intensity += [patch_intensity] * 2
        flat_share += [share] * 2
        texture += [float(energy[window].mean())] * 2
        saturation += [float(chroma[window].mean())] * 2
    count = len(labels)
    return (
        torch.stack(inputs),
        torch.tensor(labels),
        torch.full((count,), index),
        torch.tensor(radius),
        torch.tensor(intensity),
        torch.tensor(flat_share) >= FLAT_SHARE,
        torch.tensor(tops).repeat_interleave(2),
        torch.tensor(lefts).repeat_interleave(2),
        torch.tensor(texture),
        torch.tensor(saturation),
    )
