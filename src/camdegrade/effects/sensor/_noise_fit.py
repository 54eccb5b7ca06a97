"""How :meth:`Noise.fit` estimates camera noise, on flat pixels only: a closed-form start from the measured
statistics (:class:`~camdegrade.functional.analysis.noise.NoiseSums`), then simulated moments. :func:`calibrate`
is the second part alone, for a noise stage inside a longer chain (the diagnosis simulates the whole profile)."""

from __future__ import annotations

import copy
import itertools
import math
from collections.abc import Callable, Sequence
from typing import Any, ClassVar, Protocol, TypeVar

import torch
from torch import Tensor

from camdegrade._support.seeds import derived_generator
from camdegrade.effects._fitting import as_pairs
from camdegrade.effects.base import Pairs
from camdegrade.functional.analysis.images import flat_mask
from camdegrade.functional.analysis.noise import BINS, HIGH_PASS, NoiseSums, measure_set

#: A bin's noise level is estimated from at least this many flat pixels (its std then has a relative standard
#: error of a few per cent, more where the noise is correlated).
FIT_MIN_PIXELS = 500
#: The added noise's own correlation is read from the excess over the source only where the excess is at least
#: this share of the target's variance; below, the excess is mostly the two images' texture disagreeing, and the
#: target's own correlation is the better guess.
MIN_NOISE_SHARE = 0.25
#: Banding is kept when the target's line means vary more than the fitted noise leaves in them by this many
#: standard errors, and by this share of what the noise leaves.
SIGNIFICANCE = 3.0
NULL_SHARE = 0.25
#: The 17×17 local mean leaves this share of a row's (column's) constant offset in the residual.
LINE_KEPT = (HIGH_PASS - 1) / HIGH_PASS
#: One round changes a level by at most this factor.
MAX_STEP = 4.0
#: Correlation targets stay within this bound (a kernel of 5 taps reaches about 0.87 at lag 1).
MAX_CORRELATION = 0.95


class NoiseStage(Protocol):
    """What the estimator reads and sets of a noise stage (:class:`~camdegrade.effects.Noise`, which calls it: the
    estimator names no class of its own, so the stage and its fit import one way)."""

    MAX_LEVEL: ClassVar[float]
    levels: Tensor
    mixing: Tensor
    across: Tensor
    down: Tensor
    row_sigma: Tensor
    column_sigma: Tensor

    @property
    def taps(self) -> int: ...

    def make_params(self, shape: Any, generator: torch.Generator) -> dict[str, Any]: ...

    def __call__(self, image: Tensor, params: dict[str, Any]) -> Tensor: ...


NoiseT = TypeVar("NoiseT", bound=NoiseStage)
Simulate = Callable[[NoiseStage], list[Tensor]]
Measure = Callable[[list[Tensor]], NoiseSums]


def fit_noise(
    cls: type[NoiseT], source: Pairs, target: Pairs, *, estimator: str, taps: int, banding: bool, rounds: int, seed: int
) -> NoiseT:
    """:meth:`Noise.fit` (see its docstring)."""
    if estimator not in ("excess", "residual"):
        raise ValueError(f"estimator must be 'excess' or 'residual', got estimator={estimator!r}")
    if isinstance(taps, bool) or not isinstance(taps, int) or taps < 1 or taps % 2 == 0:
        raise ValueError(f"taps must be a positive odd integer, got taps={taps!r}")
    pairs = as_pairs(source, target)
    sources = [src for src, _ in pairs]
    masks = [flat_mask(src) for src in sources]
    measure = _measure_for(sources, masks, estimator)
    real, base = measure([tgt for _, tgt in pairs]), measure(sources)
    check_measurable(real)
    start = initial_noise(cls, real, base, taps)

    def simulate(noise: NoiseT) -> list[Tensor]:
        out = []
        with torch.no_grad():
            for index, src in enumerate(sources):
                batch = src[None]
                out.append(noise(batch, noise.make_params(batch.shape, derived_generator(seed, "noise-fit", index)))[0])
        return out

    return calibrate(start, simulate, measure, real, base, rounds=rounds, banding=banding)


def _measure_for(sources: Sequence[Tensor], masks: Sequence[Tensor], estimator: str) -> Measure:
    """The statistic the noise must reproduce: of each image itself (excess), or of its difference to the source
    (residual), on the source's flat pixels, binned by the source's value."""

    def measure(images: list[Tensor]) -> NoiseSums:
        total = NoiseSums.zeros()
        for image, src, mask in zip(images, sources, masks, strict=True):
            if estimator == "residual":
                total = total + NoiseSums.measure(image - src, src, mask, clipping=image)
            else:
                total = total + NoiseSums.measure(image, src, mask)
        return total

    return measure


def check_measurable(real: NoiseSums) -> None:
    measurable = torch.isfinite(real.std(FIT_MIN_PIXELS)).any(1)
    if not bool(measurable.all()):
        raise ValueError(
            f"too few flat pixels to measure noise: {real.pixels} pixels where the source is flat (an intensity bin "
            f"needs {FIT_MIN_PIXELS}); use pairs with flat regions (sky, walls, a grey card) or larger images"
        )


def initial_noise(cls: type[NoiseT], real: NoiseSums, base: NoiseSums, taps: int) -> NoiseT:
    """The closed-form start: the excess variance per bin, the excess (or the target's) correlation, no banding."""
    levels = _fill(((_variance(real) - _variance(base)).clamp_min(0)).sqrt()) / 255.0
    rho = _noise_correlation(real, base)
    across, down = _kernels(rho, taps)
    return cls(
        column_sigma=torch.zeros(3),
        levels=levels.float(),
        across=across,
        down=down,
        mixing=_mixing(_noise_channel_correlation(real, base)),
        linear=False,
    )


def flat_noise_sums(cleans: Sequence[Tensor]) -> Measure:
    """A measure of images (one per clean image, in order): their noise sums on the flat pixels of ``cleans``."""
    masks = [flat_mask(clean) for clean in cleans]
    return lambda images: measure_set(list(images), list(cleans), masks)


def calibrate(
    noise: NoiseT,
    simulate: Simulate,
    measure: Measure,
    real: NoiseSums,
    base: NoiseSums,
    *,
    rounds: int = 2,
    banding: bool = True,
    levels_rule: Callable[[Tensor], Tensor] | None = None,
) -> NoiseT:
    """``noise`` corrected by simulated moments until ``measure(simulate(noise))`` matches ``real``.

    Args:
        noise: the start (a structured stage: level table, kernel, mixing; see :func:`initial_noise`).
        simulate: the images with a noise stage in place (the same seeds every call).
        measure: their statistics; ``base`` is the same statistic without any noise stage.
        rounds: correction rounds of the level table and the correlations.
        banding: then fit row and column banding against the simulated null (none where the data show none).
        levels_rule: applied to the level table ``(3, K)`` after each correction (the unpaired fit's: smooth in
            the signal level and bounded, :mod:`camdegrade.fitting.unpaired.steps.noise`). Every table stays within
            the stage's range (:attr:`Noise.MAX_LEVEL`) whatever the rule.
    """
    if rounds < 0:
        raise ValueError(f"rounds must be >= 0, got rounds={rounds}")
    noise = copy.deepcopy(noise)
    for _ in range(rounds):
        sim = measure(simulate(noise))
        _correct_correlation(noise, real, base, sim)
        _correct_levels(noise, real, base, sim, levels_rule)
    if rounds:  # the last correlation step changed what the chain lets through: the levels follow it once more
        _correct_levels(noise, real, base, measure(simulate(noise)), levels_rule)
    if banding and hasattr(noise, "column_sigma"):
        _set_banding(noise, real, measure(simulate(_without_banding(noise))))
    return noise


# -- levels ------------------------------------------------------------------------------------------------------


def _fill(values: Tensor) -> Tensor:
    """NaN entries of ``(3, K)`` replaced by the nearest measured knot of their channel (zero where none is)."""
    out = values.clone()
    for channel in range(values.shape[0]):
        measured = torch.isfinite(values[channel]).nonzero().flatten()
        if measured.numel() == 0:
            out[channel] = 0.0
            continue
        for knot in range(values.shape[1]):
            if not torch.isfinite(values[channel, knot]):
                out[channel, knot] = values[channel, measured[(measured - knot).abs().argmin()]]
    return out


def _correct_levels(
    noise: NoiseT, real: NoiseSums, base: NoiseSums, sim: NoiseSums, rule: Callable[[Tensor], Tensor] | None = None
) -> None:
    """Each knot's std scaled by how far the simulated excess variance is from the real one (then ``rule``), at
    most the stage's :attr:`~camdegrade.effects.Noise.MAX_LEVEL`: a chain after the noise that removes nearly all
    of it (a codec's dead zone) would otherwise have the level raised 4× a round without end."""
    base_variance = _variance(base)
    wanted = _variance(real) - base_variance
    got = _variance(sim) - base_variance
    levels = noise.levels.double()
    factor = (wanted.clamp_min(0) / got.clamp_min(1e-12)).sqrt().clamp(1 / MAX_STEP, MAX_STEP)
    switched_on = wanted.clamp_min(0).sqrt() / 255.0  # a knot at zero has no response to scale
    updated = torch.where(levels > 0, levels * factor, switched_on)
    updated = torch.where(wanted <= 0, torch.zeros_like(updated), updated)
    measurable = torch.isfinite(wanted) & torch.isfinite(got)
    updated = torch.where(measurable, updated, levels)
    if rule is not None:
        updated = rule(updated)
    noise.levels.copy_(updated.clamp(0.0, type(noise).MAX_LEVEL).float())


def _variance(sums: NoiseSums) -> Tensor:
    """``(3, BINS)`` noise variance per bin (levels²), NaN where the fit has too few pixels."""
    return sums.std(FIT_MIN_PIXELS).pow(2)


# -- correlation ---------------------------------------------------------------------------------------------------


def _noise_correlation(real: NoiseSums, base: NoiseSums) -> Tensor:
    """``(2, 2, 3)`` lag-1/lag-2 correlations of the noise to add: of the excess covariance over the source where
    the excess dominates enough, else the target's own."""
    real_variance, real_lag = real.covariance()
    base_variance, base_lag = base.covariance()
    excess = real_variance - base_variance
    share = excess / real_variance
    from_excess = (real_lag - base_lag.nan_to_num(0.0)) / excess.clamp_min(1e-12)
    own = real_lag / real_variance
    rho = torch.where(share >= MIN_NOISE_SHARE, from_excess, own)
    return rho.nan_to_num(0.0).clamp(-MAX_CORRELATION, MAX_CORRELATION)


def _noise_channel_correlation(real: NoiseSums, base: NoiseSums) -> Tensor:
    real_cov = real.cross / real.cross_count.clamp_min(1)
    base_cov = base.cross / base.cross_count.clamp_min(1)
    excess = real_cov - base_cov
    share = excess.diagonal() / real_cov.diagonal().clamp_min(1e-12)
    covariance = excess if bool((share >= MIN_NOISE_SHARE).all()) else real_cov
    std = covariance.diagonal().clamp_min(1e-12).sqrt()
    return covariance / (std[:, None] * std[None, :])


def _correct_correlation(noise: NoiseT, real: NoiseSums, base: NoiseSums, sim: NoiseSums) -> None:
    """Kernel and mixing targets moved by the real − simulated difference of the measured correlations, scaled up
    by the noise's share of the simulated variance (the rest of the measured field is the source's own)."""
    if noise.taps < 3:
        return
    sim_variance, _ = sim.covariance()
    base_variance, _ = base.covariance()
    share = ((sim_variance - base_variance) / sim_variance).clamp(MIN_NOISE_SHARE, 1.0).nan_to_num(1.0)
    current = torch.stack([_autocorrelation(noise.across), _autocorrelation(noise.down)])  # (2, 2, 3)
    step = ((real.correlation() - sim.correlation()) / share).nan_to_num(0.0)
    across, down = _kernels(current + step, noise.taps)
    noise.across.copy_(across)
    noise.down.copy_(down)
    mixing = noise.mixing.double()
    channel_step = ((real.channel_correlation() - sim.channel_correlation()) / share.mean()).nan_to_num(0.0)
    noise.mixing.copy_(_mixing(mixing @ mixing.T + channel_step).float())


def _autocorrelation(kernels: Tensor) -> Tensor:
    """``(2, 3)``: the lag-1 and lag-2 autocorrelation of each channel's unit-norm taps."""
    k = kernels.double()
    lags = [(k[:, :-d] * k[:, d:]).sum(1) if k.shape[1] > d else torch.zeros(3, dtype=k.dtype) for d in (1, 2)]
    return torch.stack(lags)


def _kernels(rho: Tensor, taps: int) -> tuple[Tensor, Tensor]:
    """``(3, taps)`` unit-norm symmetric taps along x and along y whose lag-1/lag-2 autocorrelation is closest to
    ``rho`` ``(2, 2, 3)`` (axis, lag, channel)."""
    out = []
    for axis in (0, 1):
        rows = [_symmetric_taps(float(rho[axis, 0, c]), float(rho[axis, 1, c]), taps) for c in range(3)]
        out.append(torch.tensor(rows, dtype=torch.float32))
    return out[0], out[1]


def _symmetric_taps(r1: float, r2: float, taps: int) -> list[float]:
    """Unit-norm taps ``[.., c2, c1, 1, c1, c2, ..]`` (normalised) whose autocorrelation at lags 1 and 2 is as close
    as it can be to ``(r1, r2)`` (a coarse grid, then Gauss–Newton on ``(c1, c2)``)."""
    centre = taps // 2
    if taps == 1:
        return [1.0]

    def autocorrelation(c1: float, c2: float) -> tuple[float, float]:
        norm = 1 + 2 * c1 * c1 + 2 * c2 * c2
        return (2 * c1 + 2 * c1 * c2) / norm, (2 * c2 + c1 * c1) / norm

    def error(c1: float, c2: float) -> float:
        a1, a2 = autocorrelation(c1, c2)
        return (a1 - r1) ** 2 + (a2 - r2) ** 2 + 1e-6 * c2 * c2

    uses_c2 = taps >= 5
    grid = [i / 10 for i in range(-20, 41)]
    c1, c2 = min(itertools.product(grid, grid if uses_c2 else [0.0]), key=lambda c: error(*c))
    for _ in range(30):  # Gauss–Newton on the two residuals, numeric Jacobian
        h = 1e-6
        base = autocorrelation(c1, c2)
        residual = (base[0] - r1, base[1] - r2)
        d1 = [(v - b) / h for v, b in zip(autocorrelation(c1 + h, c2), base, strict=True)]
        d2 = [(v - b) / h for v, b in zip(autocorrelation(c1, c2 + h), base, strict=True)] if uses_c2 else [0.0, 0.0]
        step = _solve_2x2(d1, d2, residual, damping=1e-9 if uses_c2 else 1.0)
        trial = (c1 - step[0], c2 - step[1] if uses_c2 else 0.0)
        if error(*trial) >= error(c1, c2):
            break
        c1, c2 = trial
    kernel = [0.0] * taps
    kernel[centre] = 1.0
    kernel[centre - 1] = kernel[centre + 1] = c1
    if uses_c2:
        kernel[centre - 2] = kernel[centre + 2] = c2
    norm = math.sqrt(sum(v * v for v in kernel))
    return [v / norm for v in kernel]


def _solve_2x2(d1: list[float], d2: list[float], residual: tuple[float, float], damping: float) -> tuple[float, float]:
    """Least-squares step ``(s1, s2)`` with ``s1·d1 + s2·d2 ≈ residual`` (columns ``d1``, ``d2``), damped."""
    a11 = d1[0] * d1[0] + d1[1] * d1[1] + damping
    a12 = d1[0] * d2[0] + d1[1] * d2[1]
    a22 = d2[0] * d2[0] + d2[1] * d2[1] + damping
    b1 = d1[0] * residual[0] + d1[1] * residual[1]
    b2 = d2[0] * residual[0] + d2[1] * residual[1]
    determinant = a11 * a22 - a12 * a12
    if abs(determinant) < 1e-300:
        return 0.0, 0.0
    return (a22 * b1 - a12 * b2) / determinant, (a11 * b2 - a12 * b1) / determinant


def _mixing(correlation: Tensor) -> Tensor:
    """A ``(3, 3)`` mixing matrix with ``M Mᵀ`` the nearest valid correlation matrix to ``correlation``."""
    matrix = correlation.double().nan_to_num(0.0)
    matrix = (matrix + matrix.T) / 2
    matrix.fill_diagonal_(1.0)
    values, vectors = torch.linalg.eigh(matrix)
    matrix = vectors @ torch.diag(values.clamp_min(0.02)) @ vectors.T
    std = matrix.diagonal().sqrt()
    matrix = matrix / (std[:, None] * std[None, :])
    return torch.linalg.cholesky(matrix).float()


# -- banding -----------------------------------------------------------------------------------------------------


def _without_banding(noise: NoiseT) -> NoiseT:
    out = copy.deepcopy(noise)
    out.row_sigma.zero_()
    out.column_sigma.zero_()
    return out


def _set_banding(noise: NoiseT, real: NoiseSums, null: NoiseSums) -> None:
    """Row and column σ from the line-mean variance the real images show beyond the simulated null (the fitted
    noise without banding); zero where that excess is not significant.

    The excess rows and columns share is not banding but 2-D noise correlated further than the stage's kernel
    reaches (chroma blotches; measured in docs/results.md, *Real sensor noise: PolyU, CC15 and SIDD*), so each
    direction keeps only what it has beyond the other. Banding drawn from it printed a plaid over the whole frame. A
    camera with row and column banding loses the weaker, and the stronger its part beyond it; row banding alone (a
    sensor's usual) is kept. Only an excess significant in both directions is shared.
    """
    real_variance, real_se = real.line_variance()
    null_variance, null_se = null.line_variance()
    excess = real_variance - null_variance
    se = (real_se.pow(2) + null_se.pow(2)).sqrt()
    beyond = (excess > SIGNIFICANCE * se).all(0)  # both directions beyond their null: the shared part comes off
    shared = torch.where(beyond, excess.min(0).values, torch.zeros_like(excess[0]))
    excess = excess - shared
    se = torch.where(beyond, (se.pow(2) + se.flip(0).pow(2)).sqrt(), se)  # the subtracted estimate's error too
    kept = (excess > SIGNIFICANCE * se) & (excess > NULL_SHARE * null_variance)
    sigma = torch.where(kept, (excess.clamp_min(0) / LINE_KEPT).sqrt() / 255.0, torch.zeros_like(excess))
    noise.row_sigma.copy_(sigma[0].nan_to_num(0.0).float())
    noise.column_sigma.copy_(sigma[1].nan_to_num(0.0).float())


__all__ = ["BINS", "calibrate", "check_measurable", "fit_noise", "initial_noise"]
