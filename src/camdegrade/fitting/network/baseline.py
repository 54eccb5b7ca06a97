"""The parametric baseline every fit starts from and is compared with: one linear colour filter, by least squares.

A 7×7 filter from the three clean channels to each captured channel, with an offset (``3·49 + 1`` numbers per
channel): a camera's global colour map (the 12-number affine map), its lens blur and its sharpening are all special
cases of it. It is the simple answer a fitted network must beat: :class:`~camdegrade.network.LocalAffineNet` starts
from it (its full-resolution filter), and every fit reports the baseline's validation PSNR beside the profile's.

Solved from the normal equations accumulated pair by pair over :data:`PIXELS_PER_PAIR` random pixels of each pair
(seeded), in float64, with a small ridge for flat images whose neighbours are collinear.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade._support.pixels import as_unit
from camdegrade._support.seeds import derived_generator
from camdegrade.measures.metrics import psnr
from camdegrade.network import LINEAR_TAPS

__all__ = ["PIXELS_PER_PAIR", "RIDGE", "ImagePair", "apply_linear_baseline", "baseline_psnr", "fit_linear_baseline"]

#: Pixels sampled from each pair: 148 unknowns per channel are well determined by a few thousand; more only costs.
PIXELS_PER_PAIR = 8192
#: Ridge, relative to the mean diagonal of the normal matrix: keeps a flat image's collinear neighbours solvable
#: without moving a textured image's solution measurably.
RIDGE = 1e-6

ImagePair = tuple[Tensor, Tensor]


def fit_linear_baseline(pairs: Sequence[ImagePair], *, seed: int = 0, taps: int = LINEAR_TAPS) -> tuple[Tensor, Tensor]:
    """The least-squares linear colour filter ``captured ≈ weight ∗ clean + bias`` over ``pairs`` (``(3, H, W)``
    each, uint8 or float in [0, 1]; borders replicated as :class:`~camdegrade.network.LocalAffineNet` does).

    Returns ``(weight, bias)``: ``(3, 3, taps, taps)`` (output channel, input channel, y, x) and ``(3,)``, float32,
    ready for a ``Conv2d(3, 3, taps)``.

    Examples:
        >>> clean = torch.rand(3, 32, 32)
        >>> weight, bias = fit_linear_baseline([(clean, 0.5 * clean + 0.1)])
        >>> round(float(weight[0, 0, 3, 3]), 3), round(float(bias[0]), 3)
        (0.5, 0.1)
    """
    if not pairs:
        raise ValueError("pairs must hold at least one (clean, captured) pair, got none")
    generator = derived_generator(seed, "linear-baseline")
    unknowns = 3 * taps * taps + 1
    normal = torch.zeros(unknowns, unknowns, dtype=torch.float64)
    moments = torch.zeros(unknowns, 3, dtype=torch.float64)
    for clean, captured in pairs:
        design, target = _sampled_rows(as_unit(clean), as_unit(captured), taps, generator)
        normal += design.T @ design
        moments += design.T @ target
    ridge = RIDGE * float(normal.diagonal().mean()) * torch.eye(unknowns, dtype=torch.float64)
    solution = torch.linalg.solve(normal + ridge, moments)  # (unknowns, 3)
    weight = solution[:-1].T.reshape(3, 3, taps, taps)
    return weight.float().contiguous(), solution[-1].float().contiguous()


def _sampled_rows(clean: Tensor, captured: Tensor, taps: int, generator: torch.Generator) -> tuple[Tensor, Tensor]:
    """Rows of the least-squares problem at random pixels: each pixel's ``taps×taps`` neighbourhood of the three clean
    channels and a 1, and its captured RGB."""
    height, width = clean.shape[-2:]
    count = min(PIXELS_PER_PAIR, height * width)
    where = torch.randperm(height * width, generator=generator)[:count]
    ys, xs = where // width, where % width
    half = taps // 2
    padded = F.pad(clean[None].float(), (half, half, half, half), mode="replicate")[0]
    offsets = torch.arange(taps)
    rows = ys[:, None, None] + offsets[None, :, None]
    cols = xs[:, None, None] + offsets[None, None, :]
    patches = padded[:, rows, cols]  # (3, count, taps, taps)
    design = patches.permute(1, 0, 2, 3).reshape(count, -1).double()
    design = torch.cat([design, torch.ones(count, 1, dtype=torch.float64)], dim=1)
    target = captured[:, ys, xs].T.double()
    return design, target


def apply_linear_baseline(weight: Tensor, bias: Tensor, image: Tensor) -> Tensor:
    """The baseline's output for float ``(N, 3, H, W)`` in [0, 1], clamped to [0, 1]."""
    half = weight.shape[-1] // 2
    padded = F.pad(image, (half, half, half, half), mode="replicate")
    return F.conv2d(padded, weight.to(image), bias.to(image)).clamp(0.0, 1.0)


def baseline_psnr(
    weight: Tensor, bias: Tensor, pairs: Sequence[ImagePair], after: Callable[[Tensor], Tensor] | None = None
) -> float:
    """Mean PSNR (dB) of the baseline's output (passed through ``after``, a fixed stage, when given: the form a
    network started from the baseline and trained through that stage has) against the captures over ``pairs``."""
    if not pairs:
        raise ValueError("pairs must hold at least one (clean, captured) pair, got none")
    scores = []
    with torch.no_grad():
        for clean, captured in pairs:
            output = apply_linear_baseline(weight, bias, as_unit(clean)[None])
            scores.append(psnr((after(output) if after is not None else output)[0], as_unit(captured)))
    return sum(scores) / len(scores)
