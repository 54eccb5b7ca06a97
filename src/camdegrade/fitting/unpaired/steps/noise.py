"""Camera noise fitted from the captures alone: each capture's own flat regions, no clean reference.

Where a capture is flat (:func:`~camdegrade.functional.analysis.images.noisy_flat_mask` of the capture itself: its
gradient at 2 px below 1.5 levels or, where its own noise moves the gradient more, below what that noise explains),
its residual from the 17×17 local mean is its noise,
binned by that local mean (:class:`~camdegrade.functional.analysis.noise.NoiseSums`: level per channel and
intensity bin, lag-1/2 and channel correlation, row and column line means). The same measurement of the clean set, run
through the rest of the fitted chain, is the base (what the clean images carry already); the noise stage then
follows by simulated moments (:func:`~camdegrade.effects.sensor._noise_fit.calibrate`), so clipping, the tone curve,
sharpening and the codec after the noise are absorbed. That calibration reads the captures and every simulation
alike at the finest scale the stage models (:data:`FINE_WINDOW`, below), where a scene's texture cannot pass for
noise. The simulations are measured on the pixels where the
noiseless simulation is flat (:func:`on_noiseless_pixels`), and after each round the level table is a curve smooth
in the signal level (:func:`smooth_levels`), at most :data:`RAISE_LIMIT` times the captures' own noise
(:class:`LevelsRule`): a bin of texture in the captures no longer becomes speckle (docs/results.md, "Unpaired fit
on real PolyU captures").

**The noise read at the stage's own scale.** The calibration makes the simulation's reading match the captures',
so whatever the flat pixels of the two sets hold besides noise enters the stage: the noise added is what the
captures' flat pixels read beyond what the clean set's read, and a clean set of other scenes holds other texture.
Flat pixels are flat only to a gradient threshold; what they still hold is smooth content (shading, a curved
surface, cloth under the threshold), and its residual from a local mean grows with the window's area (a smooth
field's ``x − mean_w(x)`` is about its curvature times ``w²``), while the noise's stops growing once the window is
wider than the noise is correlated. At 17×17 (:data:`~camdegrade.functional.analysis.noise.HIGH_PASS`) the 10 PolyU
crops' own mean frames read 3.12 levels on the captures' flat pixels, their real noise 2.90; at 5×5, 1.21 and 2.36
(texture's share of the variance 54 % → 21 %). So the level, correlation and channel sums of the calibration are
taken off a 5×5 local mean (:data:`FINE_WINDOW`: the footprint of the stage's 5-tap kernel, the noise it can
make), on the captures and on every simulation alike (the same statistic on both sides, so the share of a
correlated noise it leaves out is left out of the simulated noise too). On that case the noise stage alone,
calibrated on the other scenes' mean frames, reads 2.77 levels at mid grey, on the captures' own 2.62; at 17×17 it
read 1.66 and 1.75, with channels between 0.6 and 3.6 where the scenes' texture fell (docs/results.md, "The PolyU
unpaired noise read at the stage's scale"; ``experiments/unpaired_noise_window.py``). The captures-only noise
(below) is read at 17×17: there the reading is the stage, with no simulation to leave the same share out.

**Captures only, nothing after the noise** (``direct=True``): the stage is the captures' own measured moments, per
channel and intensity bin, with no base taken off and no simulated correction (banding is still fitted). There the
simulated moments mislead: the calibration makes the simulation's *own* flat-pixel reading match the captures'
within 1 %, yet moves the stage away from the camera's noise (on the real PolyU / CC15 captures, median |log2| per
bin against the clean-referenced noise of other captures 0.11 / 0.27 direct, 0.25 / 0.39 calibrated even on the
true clean images; ``examples/noise_table_unpaired.py --calibrated``); and the stand-ins (captures blurred, in
place of a clean set) keep part of the captures' correlated noise, which taking them off as a base removes from the
stage.

**The level table made smooth in the signal level**, as a sensor's noise is, where the captures' own flat pixels
read it bin by bin. A sensor's noise is Poisson–Gaussian in the raw signal (its variance affine in the signal), and
a camera's tone curve, demosaicking and denoising bend that smoothly: the std of a processed image's noise changes
gradually from one intensity to the next. The unpaired fit reads it per channel and intensity bin from each
capture's own flat pixels, and a bin often rests on one or two captures: where their "flat" pixels hold texture,
that bin reads several times the noise (10 PolyU crops of 128²: red bin 1 at 6.4 levels where each capture against
its own mean frame shows 2.8), and the calibration then raised it further (a table entry of 19.2 levels beside 0.3
and 0.7; flat greys painted with 16–20 levels of green and magenta speckle; docs/results.md, "Unpaired fit on real
PolyU captures").

The table is therefore replaced by a smooth curve through it (:func:`smooth_levels`): per channel, the log std
that stays close to each bin's value, weighted by the bin's support (its flat pixels, :data:`HALF_SUPPORT`), and
whose second differences are small (:data:`CURVATURE`; an affine variance has almost none in the log std over
the middle of the range). Texture only adds to a bin's variance, so a bin far *above* the curve is down-weighted
(:data:`TEXTURE_LOG2`, iterated), one below it is not.

References:
    E. T. Whittaker, "On a new method of graduation", Proceedings of the Edinburgh Mathematical Society 41, 1923
    (the penalised smoother); P. H. C. Eilers, "A perfect smoother", Analytical Chemistry 75(14), 2003;
    A. Foi, M. Trimeche, V. Katkovnik, K. Egiazarian, "Practical Poissonian-Gaussian noise modeling and fitting for
    single-image raw-data", IEEE TIP 17(10), 2008 (noise levels per intensity from smooth regions, and the clipped
    Poisson–Gaussian curve they follow).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import torch
from torch import Tensor

from camdegrade.effects import Effect, FrequencyResponse, Noise
from camdegrade.effects.sensor._noise_fit import FIT_MIN_PIXELS, calibrate, check_measurable, initial_noise
from camdegrade.fitting.unpaired.bench import UnpairedFit, UnpairedStep
from camdegrade.functional.analysis.images import box_mean, noisy_flat_mask
from camdegrade.functional.analysis.noise import HIGH_PASS, NoiseSums, measure_set

__all__ = [
    "CURVATURE",
    "FINE_WINDOW",
    "FLOOR_LEVELS",
    "HALF_SUPPORT",
    "NOISE_FLOOR",
    "NOISE_SHARE",
    "RAISE_LIMIT",
    "ROUNDS",
    "SLOPE",
    "TEXTURE_LOG2",
    "LevelsRule",
    "NoiseMatch",
    "NoiseProposal",
    "captures_noise",
    "fit_noise_unpaired",
    "flat_sums",
    "judge_noise",
    "on_noiseless_pixels",
    "own_check_noise",
    "propose_noise",
    "smooth_levels",
    "without_moments",
]

#: A noise stage is kept when its std at mid-grey is at least this many 8-bit levels (8-bit rounding alone leaves
#: about 0.3).
NOISE_FLOOR = 0.5
#: ... and when the captures' flat pixels vary at least this much more than the simulated clean set's without it
#: (the rest is the two sets' content, not noise).
NOISE_SHARE = 1.1
#: A knot's level is at most this many times the captures' own noise there (their flat pixels, smoothed). The chain
#: after the noise may take some of it away (a JPEG's dead zone: 2 levels come through quality 85 as 0.8), but
#: where the simulated noise stays far below the captures' whatever the level (their flat pixels hold texture or
#: codec blocks the clean set's do not, or the codec is heavier than the camera's), each calibration round raised
#: the level 4× more: 64× in three rounds, past the stage's range (a level of 510 of 255 from 30 levels of white
#: noise behind a simulated quality-10 JPEG), and the profile could not be saved.
RAISE_LIMIT = 4.0
#: The side of the local mean the calibrated noise reading takes off (see the module): the footprint of the stage's
#: 5-tap kernel.
FINE_WINDOW = 5


def flat_sums(images: Sequence[Tensor], window: int = HIGH_PASS) -> NoiseSums:
    """The noise sums of each image on its own flat pixels
    (:func:`~camdegrade.functional.analysis.images.noisy_flat_mask`), binned by its own local mean; ``window``:
    the local mean's side taken off (:meth:`~camdegrade.functional.analysis.noise.NoiseSums.measure`)."""
    total = NoiseSums.zeros()
    for image in images:
        total = total + NoiseSums.measure(image, box_mean(image, HIGH_PASS), noisy_flat_mask(image), window=window)
    return total


def captures_noise(fit: UnpairedFit, direct: bool) -> NoiseSums:
    """The captures' :func:`flat_sums` the noise step matches: read at :data:`FINE_WINDOW` for the calibration
    (measured when first asked for), at 17×17 (``fit.sets.real_noise``) where the stage is read straight."""
    if direct:
        return fit.sets.real_noise
    if fit.sets.fine_noise is None:
        fit.sets.fine_noise = flat_sums(fit.captures.images, FINE_WINDOW)
    return fit.sets.fine_noise


def own_check_noise(fit: UnpairedFit, simulated: Sequence[Tensor]) -> tuple[float, float]:
    """The own check's flat-pixel noise (pooled std, levels) of the simulated clean set and of the captures: read as
    the calibration reads them, at :data:`FINE_WINDOW`, where there is a clean set (other scenes, whose texture at
    17×17 the check read as the stage's error: on the PolyU case the clean set with no stage read 0.44 of the
    captures, their own mean frames 0.75; at 5×5 the fitted profile reads 0.76 with either); at 17×17 without one
    (the stand-ins are the captures smoothed, and the captures-only stage is that reading)."""
    if fit.cleans is None:
        return flat_sums(simulated).pooled_std(), fit.sets.real_noise.pooled_std()
    return flat_sums(simulated, FINE_WINDOW).pooled_std(), captures_noise(fit, direct=False).pooled_std()


def on_noiseless_pixels(
    noiseless: Sequence[Tensor], window: int = HIGH_PASS
) -> Callable[[Sequence[Tensor]], NoiseSums]:
    """A measure of the clean set simulated with noise (one image per ``noiseless`` image, in order): the noise sums
    on the pixels where the simulation *without* noise is flat, binned by its local mean, the same pixels every
    call. Measured on each simulation's own noise-adapted mask (:func:`flat_sums`), the pixels changed with the
    noise added: more noise admitted more texture, and the excess over the noiseless base was not the stage's
    noise (10 PolyU crops: 0.0–5.2 levels for stage levels of 0.5–7, falling while the levels rose), which the
    calibration, a factor up to 4 per bin and round, then chased. ``window``: as in :func:`flat_sums`."""
    means = [box_mean(image, HIGH_PASS) for image in noiseless]
    masks = [noisy_flat_mask(image) for image in noiseless]
    return lambda images: measure_set(list(images), means, masks, window=window)


def fit_noise_unpaired(
    real: NoiseSums, simulate: Callable[[Noise | None], list[Tensor]], **options: Any
) -> tuple[Noise | None, dict]:
    """The noise stage whose simulation on the clean set matches ``real`` (the captures' :func:`flat_sums`, read as
    :func:`propose_noise` says), or ``None`` below :data:`NOISE_FLOOR` or :data:`NOISE_SHARE`; and notes for the
    metadata: :func:`propose_noise` (``options`` are its keywords), then :func:`judge_noise`."""
    proposal = propose_noise(real, simulate, **options)
    return judge_noise(proposal, real), proposal.notes


@dataclass(frozen=True)
class NoiseProposal:
    """A noise stage fitted to the captures, the clean set's flat-pixel noise without it, the notes, and the
    captures' reading it matched."""

    noise: Noise
    base: NoiseSums
    notes: dict
    real: NoiseSums


def propose_noise(
    real: NoiseSums,
    simulate: Callable[[Noise | None], list[Tensor]],
    *,
    taps: int = 5,
    banding: bool = True,
    rounds: int = 2,
    direct: bool = False,
    window: int = FINE_WINDOW,
) -> NoiseProposal:
    """The noise stage whose simulation on the clean set matches ``real``: the captures' :func:`flat_sums` read at
    ``window`` (calibrated, the simulations read the same way), or at its default 17×17 with ``direct`` (the stage
    is that reading; :func:`captures_noise`).

    ``simulate(noise)`` runs the clean set through the fitted chain with ``noise`` in place (``None``: without
    noise; fixed seeds).

    References:
        A. Foi, M. Trimeche, V. Katkovnik, K. Egiazarian, "Practical Poissonian-Gaussian noise modeling and fitting
        for single-image raw-data", IEEE Transactions on Image Processing 17(10), 2008 (noise level per intensity
        from a single image's smooth regions).
    """
    check_measurable(real)
    noiseless = simulate(None)
    measure = flat_sums if direct else on_noiseless_pixels(noiseless, window)
    base = measure(noiseless)
    source = without_moments(real) if direct else base
    start = initial_noise(Noise, real, source, taps)
    rule = LevelsRule(real)
    with torch.no_grad():
        start.levels.copy_(rule(start.levels.double()).float())
    noise = calibrate(
        start, simulate, measure, real, source, rounds=0 if direct else rounds, banding=banding, levels_rule=rule
    )
    notes = {
        "std_mid_grey_levels": round(noise.magnitude(), 3),
        "flat_pixels": real.pixels,
        "captures_std_levels": _rounded(real.pooled_std()),
        "clean_std_levels": _rounded(base.pooled_std()),
        "direct": direct,
        "reading_window": HIGH_PASS if direct else window,
        "levels": [[round(float(v) * 255, 2) for v in row] for row in noise.levels],
    }
    capped = (noise.levels.double() >= rule.limit * (1 - 1e-6)) & (noise.levels.double() > 0)
    if bool(capped.any()):
        notes["capped_knots"] = capped.nonzero().tolist()
    return NoiseProposal(noise, base, notes, real)


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
        return propose_noise(captures_noise(fit, direct), simulate, direct=direct)

    def judge(self, fit: UnpairedFit, proposal: NoiseProposal) -> dict:
        noise = judge_noise(proposal, proposal.real)
        fit.keep(noise, Noise)
        fit.say(f"noise: {proposal.notes['std_mid_grey_levels']} levels at mid-grey{'' if noise else ' (not kept)'}")
        return proposal.notes


class LevelsRule:
    """What the level table of an unpaired noise stage keeps after each calibration round: smooth in the signal
    level (:func:`smooth_levels`, weighted by the captures' flat pixels per bin),
    and at most :data:`RAISE_LIMIT` times the captures' own noise there (:attr:`limit`, ``(3, K)``)."""

    def __init__(self, real: NoiseSums) -> None:
        self.support = real.count
        own = smooth_levels(real.std(FIT_MIN_PIXELS) / 255.0, real.count)
        self.limit = (RAISE_LIMIT * own).clamp(max=Noise.MAX_LEVEL)

    def __call__(self, levels: Tensor) -> Tensor:
        return torch.minimum(smooth_levels(levels, self.support), self.limit.to(levels.dtype))


#: A bin with this many flat pixels counts half as much as one with very many (weight ``n / (n + HALF_SUPPORT)``).
HALF_SUPPORT = 2000.0
#: Weight of the squared second differences of the log2 std, and of the first differences (which keep the curve
#: flat, not extrapolated, beyond the bins that were measured).
CURVATURE = 1.0
SLOPE = 0.1
#: A bin this far above the curve (log2 std) keeps half its weight, twice as far a fifth: texture read as noise.
TEXTURE_LOG2 = 0.5
ROUNDS = 4
#: Levels below this (8-bit) are read as this in the log: a table entry at zero (the captures showing no more than
#: the clean set there) pulls the curve down, not to minus infinity.
FLOOR_LEVELS = 0.5


def smooth_levels(levels: Tensor, support: Tensor) -> Tensor:
    """``(3, K)`` std per channel and knot (units of [0, 1]; NaN: not measured) as the smooth curve through them
    (see the module), ``support`` ``(3, K)`` the flat pixels behind each knot. Channels with no measured knot stay
    as they were."""
    knots = levels.shape[-1]
    if knots < 3:
        return levels.clone()
    values = levels.double() * 255.0
    measured = torch.isfinite(values) & (support > 0)
    logs = torch.where(measured, values.clamp_min(FLOOR_LEVELS).log2(), torch.zeros_like(values))
    base_weight = torch.where(measured, support.double() / (support.double() + HALF_SUPPORT), torch.zeros_like(values))
    penalty = _penalty(knots)
    out = values.clone()
    for channel in range(values.shape[0]):
        if not bool(measured[channel].any()):
            continue
        weight = base_weight[channel]
        for _ in range(ROUNDS + 1):
            curve = torch.linalg.solve(torch.diag(weight) + penalty, weight * logs[channel])
            above = (logs[channel] - curve).clamp_min(0.0)
            weight = base_weight[channel] / (1.0 + (above / TEXTURE_LOG2) ** 2)
        out[channel] = curve.exp2()
    return (out / 255.0).to(levels.dtype)


def _penalty(knots: int) -> Tensor:
    second = torch.zeros(knots - 2, knots, dtype=torch.float64)
    first = torch.zeros(knots - 1, knots, dtype=torch.float64)
    for row in range(knots - 2):
        second[row, row : row + 3] = torch.tensor([1.0, -2.0, 1.0], dtype=torch.float64)
    for row in range(knots - 1):
        first[row, row : row + 2] = torch.tensor([-1.0, 1.0], dtype=torch.float64)
    ridge = 1e-6 * torch.eye(knots, dtype=torch.float64)  # a channel measured at one knot only: flat through it
    return CURVATURE * second.T @ second + SLOPE * first.T @ first + ridge


def without_moments(sums: NoiseSums) -> NoiseSums:
    """``sums`` with every pixel and line count kept and every moment at zero: a noiseless source measured on the
    same pixels (the base of a stage read straight from ``sums``)."""
    zeros = NoiseSums.zeros()
    lag_counts = sums.lag * torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=sums.lag.dtype)
    line_counts = sums.lines * torch.tensor([0.0, 0.0, 1.0], dtype=sums.lines.dtype)
    return NoiseSums(sums.count.clone(), zeros.square, lag_counts, zeros.cross, sums.cross_count.clone(), line_counts)


def _rounded(value: float) -> float | None:
    return round(value, 3) if value == value else None
