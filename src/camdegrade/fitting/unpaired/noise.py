"""Camera noise fitted from the captures alone: each capture's own flat regions, no clean reference.

Where a capture is flat (:func:`~camdegrade.functional.analysis.noisy_flat_mask` of the capture itself: its
gradient at 2 px below 1.5 levels or, where its own noise moves the gradient more, below what that noise explains),
its residual from the 17×17 local mean is its noise,
binned by that local mean (:class:`~camdegrade.functional.noise_stats.NoiseSums`: level per channel and intensity
bin, lag-1/2 and channel correlation, row and column line means). The same measurement of the clean set, run
through the rest of the fitted chain, is the base (what the clean images carry already); the noise stage then
follows by simulated moments (:func:`~camdegrade.effects._noise_fit.calibrate`), so clipping, the tone curve,
sharpening and the codec after the noise are absorbed.

**Captures only, nothing after the noise** (``direct=True``): the stage is the captures' own measured moments, per
channel and intensity bin, with no base taken off and no simulated correction (banding is still fitted). There the
simulated moments mislead: the calibration makes the simulation's *own* flat-pixel reading match the captures'
within 1 %, yet moves the stage away from the camera's noise (on the real PolyU / CC15 captures, median |log2| per
bin against the clean-referenced noise of other captures 0.11 / 0.27 direct, 0.25 / 0.39 calibrated even on the
true clean images; ``examples/noise_table_unpaired.py --calibrated``); and the stand-ins (captures blurred, in
place of a clean set) keep part of the captures' correlated noise, which taking them off as a base removes from the
stage.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import Tensor

from camdegrade.effects import Effect, FrequencyResponse, Noise
from camdegrade.effects._noise_fit import calibrate, check_measurable, initial_noise
from camdegrade.fitting.unpaired.bench import UnpairedFit, UnpairedStep
from camdegrade.functional.analysis import box_mean, noisy_flat_mask
from camdegrade.functional.noise_stats import HIGH_PASS, NoiseSums

#: A noise stage is kept when its std at mid-grey is at least this many 8-bit levels (8-bit rounding alone leaves
#: about 0.3).
NOISE_FLOOR = 0.5
#: ... and when the captures' flat pixels vary at least this much more than the simulated clean set's without it
#: (the rest is the two sets' content, not noise).
NOISE_SHARE = 1.1


def flat_sums(images: Sequence[Tensor]) -> NoiseSums:
    """The noise sums of each image on its own flat pixels (:func:`~camdegrade.functional.analysis.noisy_flat_mask`),
    binned by its own local mean."""
    total = NoiseSums.zeros()
    for image in images:
        total = total + NoiseSums.measure(image, box_mean(image, HIGH_PASS), noisy_flat_mask(image))
    return total


@dataclass(frozen=True)
class NoiseProposal:
    """A noise stage fitted to the captures, the clean set's flat-pixel noise without it, and the notes."""

    noise: Noise
    base: NoiseSums
    notes: dict


def propose_noise(
    real: NoiseSums,
    simulate: Callable[[Noise | None], list[Tensor]],
    *,
    taps: int = 5,
    banding: bool = True,
    rounds: int = 2,
    direct: bool = False,
) -> NoiseProposal:
    """The noise stage whose simulation on the clean set matches ``real`` (the captures' :func:`flat_sums`).

    ``simulate(noise)`` runs the clean set through the fitted chain with ``noise`` in place (``None``: without
    noise; fixed seeds).

    References:
        A. Foi, M. Trimeche, V. Katkovnik, K. Egiazarian, "Practical Poissonian-Gaussian noise modeling and fitting
        for single-image raw-data", IEEE Transactions on Image Processing 17(10), 2008 (noise level per intensity
        from a single image's smooth regions).
    """
    check_measurable(real)
    base = flat_sums(simulate(None))
    source = without_moments(real) if direct else base
    start = initial_noise(Noise, real, source, taps)
    noise = calibrate(start, simulate, flat_sums, real, source, rounds=0 if direct else rounds, banding=banding)
    notes = {
        "std_mid_grey_levels": round(noise.magnitude(), 3),
        "flat_pixels": real.pixels,
        "captures_std_levels": _rounded(real.pooled_std()),
        "clean_std_levels": _rounded(base.pooled_std()),
        "direct": direct,
    }
    return NoiseProposal(noise, base, notes)


def judge_noise(proposal: NoiseProposal, real: NoiseSums) -> Noise | None:
    """The stage, kept where its std at mid-grey is at least :data:`NOISE_FLOOR` and the captures' flat pixels vary
    :data:`NOISE_SHARE` times more than the simulated clean set's without it."""
    level = proposal.noise.magnitude()
    kept = level >= NOISE_FLOOR and real.pooled_std() >= NOISE_SHARE * proposal.base.pooled_std()
    return proposal.noise if kept else None


@dataclass(frozen=True)
class NoiseMatch(UnpairedStep):
    """The noise step: calibrated through the whole chain (read straight from the captures where there is no clean
    set and nothing after the noise); ``refit``: once more where a detail response is kept (it shapes the noise
    before it, as the camera's does)."""

    name: ClassVar[str] = "noise"
    kinds: ClassVar[tuple[type[Effect], ...]] = (Noise,)
    refit: bool = False

    def applies(self, fit: UnpairedFit) -> bool:
        return not self.refit or fit.stages.get(FrequencyResponse.name) is not None

    def propose(self, fit: UnpairedFit) -> NoiseProposal:
        def simulate(noise: Noise | None) -> list[Tensor]:
            return fit.simulate(fit.chain(noise=noise), fit.sets.noise_crops, "unpaired-noise")

        direct = fit.cleans is None and not fit.stages_after(Noise)
        return propose_noise(fit.sets.real_noise, simulate, direct=direct)

    def judge(self, fit: UnpairedFit, proposal: NoiseProposal) -> dict:
        noise = judge_noise(proposal, fit.sets.real_noise)
        fit.keep(noise, Noise)
        fit.say(f"noise: {proposal.notes['std_mid_grey_levels']} levels at mid-grey{'' if noise else ' (not kept)'}")
        return proposal.notes


def without_moments(sums: NoiseSums) -> NoiseSums:
    """``sums`` with every pixel and line count kept and every moment at zero: a noiseless source measured on the
    same pixels (the base of a stage read straight from ``sums``)."""
    zeros = NoiseSums.zeros()
    lag_counts = sums.lag * torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=sums.lag.dtype)
    line_counts = sums.lines * torch.tensor([0.0, 0.0, 1.0], dtype=sums.lines.dtype)
    return NoiseSums(sums.count.clone(), zeros.square, lag_counts, zeros.cross, sums.cross_count.clone(), line_counts)


def _rounded(value: float) -> float | None:
    return round(value, 3) if value == value else None
