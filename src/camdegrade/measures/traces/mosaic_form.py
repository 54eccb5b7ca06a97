"""A Bayer mosaic's form in the luma phases: a diagonal (checker) contrast that a pattern of rows times columns has not.

Luma's 2×2 phase energies (:func:`~camdegrade.functional.sensor.cfa.luma_phases`) split, in logs, into a row contrast
ρ, a column contrast κ and a checker contrast χ (the two diagonals against each other). A pattern every channel
shares, from a resampler (rows interpolated, then columns), a JPEG grid or a readout, is a product of a row pattern and
a column pattern: its χ is nil, whatever the size of ρ and κ. A mosaic is not: its two green sites lie on one
diagonal, alike, and red's and blue's on the other, unlike each other and unlike green (behind a JPEG with 4:2:0
chroma, blue's site holds the least energy, 0.114 of a sampled colour against green's 0.587), so χ is about as large
as ρ and κ (one site of four apart from three alike: |χ| = |ρ| = |κ|, a ratio of 1/√2). The form is read by that
ratio, not by the size of one site's ratio: a faint mosaic and a strong resampler's pattern are told apart.

The bars come from sets without a mosaic of their own making (docs/results.md, *The cfa stage proposed by the
mosaic's form*): on 64 images of 128² (clean, JPEG 10-95, PIL and torch upscales by 1.25-3, a sample-aligned 2×
bilinear upscale with and without noise and JPEG, the foreign cameras without a mosaic, City100 and PolyU captures)
χ over the row and column contrast reads at most 0.21 where they hold a pattern (the aligned upscale with noise: its
energies are not exactly a product), and |χ| at most 0.012 where they hold none. A set holds a mosaic's form where the
bootstrap bound (over images) of |χ| less :data:`FORM_RATIO` of the row and column contrast exceeds
:data:`CHECKER_FLOOR`.

References:
    A. C. Popescu, H. Farid, "Exposing digital forgeries in color filter array interpolated images", IEEE Trans.
    Signal Processing 53(10), 2005 (the periodic trace of interpolation); B. E. Bayer, "Color imaging array", US
    patent 3,971,065, 1976 (the layout: two greens on a diagonal).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from camdegrade.functional.sensor.cfa import bayer_masks, luma_phases

__all__ = [
    "CHECKER_FLOOR",
    "FORM_RATIO",
    "FORM_ROUNDS",
    "MosaicForm",
    "form_margin",
    "form_vector",
    "greens_alike",
    "phase_contrasts",
    "read_form",
]

#: χ must exceed this share of the row and column contrast (the null's largest: 0.21) ...
FORM_RATIO = 0.25
#: ... by at least this (log units; the null's largest |χ| without a pattern: 0.012).
CHECKER_FLOOR = 0.012
#: Bootstrap rounds (over images).
FORM_ROUNDS = 200


def phase_contrasts(phases: Tensor) -> tuple[float, float, float]:
    """``(ρ, κ, χ)`` of a ``(2, 2)`` of phase energies: the row, column and checker (main diagonal over the other)
    contrasts of their logs."""
    logs = phases.double().clamp_min(1e-12).log()
    rho = (logs[0, 0] + logs[0, 1] - logs[1, 0] - logs[1, 1]) / 4
    kappa = (logs[0, 0] + logs[1, 0] - logs[0, 1] - logs[1, 1]) / 4
    chi = (logs[0, 0] + logs[1, 1] - logs[0, 1] - logs[1, 0]) / 4
    return float(rho), float(kappa), float(chi)


def form_margin(phases: Tensor) -> float:
    """|χ| less :data:`FORM_RATIO` of the row and column contrast and :data:`CHECKER_FLOOR`: above 0 for a mosaic's
    form, below for none or a pattern of rows times columns."""
    rho, kappa, chi = phase_contrasts(phases)
    return abs(chi) - FORM_RATIO * (rho * rho + kappa * kappa) ** 0.5 - CHECKER_FLOOR


def greens_alike(phases: Tensor, pattern: str) -> bool:
    """Whether ``pattern``'s two green sites are nearer each other (in logs) than its red and blue sites are."""
    logs = phases.double().clamp_min(1e-12).log()
    masks = bayer_masks(2, 2, pattern).bool()
    greens, red, blue = logs[masks[1]], logs[masks[0]][0], logs[masks[2]][0]
    return bool(abs(greens[0] - greens[1]) < abs(red - blue))


@dataclass(frozen=True)
class MosaicForm:
    """The form read in a set of images: the margin (:func:`form_margin`) of their mean luma phases, its bootstrap
    bound (2.5 %, over images) and the checker over the row and column contrast."""

    margin: float
    bound: float
    ratio: float

    @property
    def held(self) -> bool:
        return self.bound > 0


def read_form(phases: Tensor, generator: torch.Generator) -> MosaicForm:
    """:class:`MosaicForm` of a set of images' luma phases (``(N, 2, 2)``, one per image:
    :func:`~camdegrade.functional.sensor.cfa.luma_phases`; ``generator`` draws the bootstrap)."""
    rho, kappa, chi = phase_contrasts(phases.mean(0))
    draws = torch.randint(0, len(phases), (FORM_ROUNDS, len(phases)), generator=generator)
    margins = torch.tensor([form_margin(phases[draw].mean(0)) for draw in draws])
    ratio = abs(chi) / max((rho * rho + kappa * kappa) ** 0.5, 1e-12)
    return MosaicForm(form_margin(phases.mean(0)), float(torch.quantile(margins, 0.025)), ratio)


def form_vector(images: Sequence[Tensor]) -> Tensor:
    """``(ρ, κ, χ)`` (:func:`phase_contrasts`) of the mean luma phases of ``images``: the whole 2×2 form, by which a
    simulated mosaic is compared with the captures' (a stage can match blue's site over red's and still overshoot the
    diagonal contrast threefold: docs/results.md, *The cfa stage proposed by the mosaic's form*)."""
    return torch.tensor(phase_contrasts(torch.stack([luma_phases(image) for image in images]).mean(0)))
