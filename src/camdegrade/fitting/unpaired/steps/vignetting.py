"""Vignetting from two sets of different scenes: the captures' mean radial luma profile over the clean set's (over a
flat field without one), kept where it stands out of what the sets' content moves it by
(:mod:`camdegrade.fitting.unpaired.judges`)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import Tensor

from camdegrade.effects import Effect, Vignetting
from camdegrade.effects._fitting import downscale
from camdegrade.fitting.unpaired.bench import UnpairedFit, UnpairedStep
from camdegrade.fitting.unpaired.judges import significant, split_half_error
from camdegrade.functional import relative_radius, srgb_to_linear
from camdegrade.functional.analysis.images import luma

__all__ = ["RINGS", "VignettingMatch", "estimate_vignetting", "judge_vignetting", "ring_profiles"]

#: A vignetting is kept when its corner gain differs from 1 by more than this.
VIGNETTING_FLOOR = 0.04
#: Rings of relative radius of the vignetting profile, and the side the images are averaged down to first.
RINGS = 8
RING_SIDE = 128


def ring_profile(image: Tensor) -> Tensor:
    """``(RINGS,)`` log mean linear luma per ring of relative radius, less the central ring's (vignetting's trace)."""
    small = luma(downscale(srgb_to_linear(image.double()), RING_SIDE))
    radius = relative_radius(*small.shape, torch.float64, small.device)
    rings = (radius * RINGS).long().clamp(max=RINGS - 1).flatten()
    means = torch.bincount(rings, small.flatten(), RINGS) / torch.bincount(rings, minlength=RINGS).clamp_min(1)
    return means.clamp_min(1e-4).log() - means[0].clamp_min(1e-4).log()


def ring_profiles(images: Sequence[Tensor]) -> Tensor:
    """``(N, RINGS)``: :func:`ring_profile` of each image."""
    return torch.stack([ring_profile(image) for image in images])


def _ring_moments(height: int, width: int) -> tuple[Tensor, Tensor]:
    """Mean ``r²`` and ``r⁴`` per ring of a frame of this shape (averaged down as :func:`ring_profile` does)."""
    factor = max(height, width) / RING_SIDE
    if factor > 1:
        height, width = max(1, round(height / factor)), max(1, round(width / factor))
    radius = relative_radius(height, width, torch.float64, torch.device("cpu")).flatten()
    rings = (radius * RINGS).long().clamp(max=RINGS - 1)
    count = torch.bincount(rings, minlength=RINGS).clamp_min(1)
    return (torch.bincount(rings, radius**2, RINGS) / count, torch.bincount(rings, radius**4, RINGS) / count)


def vignetting_step(difference: Tensor, shape: tuple[int, int]) -> tuple[float, float]:
    """``(k1, k2)`` of the gain ``1 + k1 r² + k2 r⁴`` whose ring means, relative to the centre's, are
    ``exp(difference)`` (linear least squares after multiplying out the centre's gain)."""
    r2, r4 = _ring_moments(*shape)
    ratio = difference.exp()
    design = torch.stack([r2 - ratio * r2[0], r4 - ratio * r4[0]], 1)
    solution = torch.linalg.lstsq(design, (ratio - 1)[:, None]).solution[:, 0]
    return float(solution[0]), float(solution[1])


def estimate_vignetting(
    real: Tensor, reference: Tensor, shape: tuple[int, int], simulate: Callable[[Vignetting], Tensor] | None
) -> tuple[float, float]:
    """``(k1, k2)`` of the vignetting from the captures' mean ring profile (``real``, :func:`ring_profiles`
    ``(N, RINGS)``) over ``reference``'s (the clean set's ``(M, RINGS)``; a flat field where it has no rows), then,
    with ``simulate``, one round of simulated moments: the clean set's ring profiles through the chain with that
    vignetting against the captures' (a tone curve after the optics bends the falloff).

    References:
        D. B. Goldman, "Vignette and exposure calibration and compensation", IEEE TPAMI 32(12), 2010 (the radial
        falloff read from the statistics of many frames).
    """
    base = reference.mean(0) if len(reference) else torch.zeros(RINGS, dtype=torch.float64)
    k1, k2 = vignetting_step(real.mean(0) - base, shape)
    if simulate is not None:
        d1, d2 = vignetting_step(real.mean(0) - simulate(Vignetting(k1, k2)).mean(0), shape)
        k1, k2 = k1 + d1, k2 + d2
    return max(-10.0, min(10.0, k1)), max(-10.0, min(10.0, k2))


def judge_vignetting(
    k1: float, k2: float, real: Tensor, reference: Tensor, shape: tuple[int, int], seed: int = 0
) -> tuple[Vignetting | None, dict]:
    """The vignetting ``(k1, k2)`` kept where its corner gain differs from 1 by more than :data:`VIGNETTING_FLOOR`
    and :data:`~camdegrade.fitting.unpaired.judges.SIGNIFICANCE` standard errors of the content (the corner gain of
    random halves of both sets' ring profiles); and its record."""

    def corner(real_indices: list[int], clean_indices: list[int]) -> Tensor:
        base = reference[clean_indices].mean(0) if len(reference) else torch.zeros(RINGS, dtype=torch.float64)
        k1, k2 = vignetting_step(real[real_indices].mean(0) - base, shape)
        return torch.tensor([k1 + k2], dtype=torch.float64)

    error = split_half_error(corner, len(real), max(len(reference), 1), seed)
    kept = significant(torch.tensor([k1 + k2]), error, VIGNETTING_FLOOR)
    notes = {
        "k1": round(k1, 4),
        "k2": round(k2, 4),
        "corner_gain": round(1 + k1 + k2, 4),
        "error": round(float(error), 4),
    }
    return (Vignetting(k1, k2) if kept else None), notes


@dataclass(frozen=True)
class VignettingMatch(UnpairedStep):
    """The vignetting step: the captures' radial falloff over the clean set's (over a flat field without one), and
    with ``simulated`` (a refit once the chain before it stands; it needs the clean set) through the chain."""

    name: ClassVar[str] = "vignetting"
    kinds: ClassVar[tuple[type[Effect], ...]] = (Vignetting,)
    simulated: bool = False

    def applies(self, fit: UnpairedFit) -> bool:
        return not self.simulated or fit.cleans is not None

    def propose(self, fit: UnpairedFit) -> tuple[float, float, tuple[int, int]]:
        def simulate(vignetting: Vignetting) -> Tensor:
            chain = fit.deterministic(vignetting=vignetting)
            return ring_profiles(fit.simulate(chain, fit.sets.small_cleans, "unpaired-deterministic"))

        sizes = torch.tensor([list(image.shape[-2:]) for image in fit.captures.images])
        shape = tuple(int(v) for v in sizes.median(0).values)
        k1, k2 = estimate_vignetting(
            fit.sets.real_rings, fit.sets.clean_rings, shape, simulate if self.simulated else None
        )
        return k1, k2, shape

    def judge(self, fit: UnpairedFit, proposal: tuple[float, float, tuple[int, int]]) -> dict:
        k1, k2, shape = proposal
        vignetting, notes = judge_vignetting(k1, k2, fit.sets.real_rings, fit.sets.clean_rings, shape, fit.seed)
        fit.keep(vignetting, Vignetting)
        fit.say(f"vignetting: corner gain {notes['corner_gain']}{'' if vignetting else ' (not kept)'}")
        return notes
