"""Simulation-calibrated noise fit: the noise stage's level chosen so that the *simulated chain* reproduces the
real captures' noise-level function.

``Noise.fit`` is closed-form: it measures the residual variance at the end of the chain and reads it as the
variance at the sensor. Every stage after the sensor changes it — a tone curve stretches or squeezes it by
intensity, a codec removes part of it, clipping truncates it — and real cameras have such stages whatever their
parametric form. This module corrects the closed-form fit by the method of simulated moments: it simulates the
profile with the candidate noise stage on the calibration clean images, measures the same statistic on the
simulations and on the real captures (the ``noise`` family of :mod:`camdegrade.diagnose.stats`: the variance of
the high-passed residual on flat pixels, per channel and bin of clean value), and rescales the stage's two
terms (the signal-dependent ``a`` and the constant ``b`` with its row banding) so that the two match.

The chain's response to each term is measured, not assumed: one simulation with the ``a`` term alone and one
with the ``b`` term alone give, per bin, how much simulated variance each term contributes; a simulation with
both, at the current level, rescales the two responses to what the chain actually does there (their
interaction shared in proportion). A weighted non-negative least-squares fit of the real excess variance on the
two responses gives the factors on ``a`` and ``b``. That step is repeated at the new level, one simulation each
time, because codecs and clipping respond non-linearly.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from camdegrade.diagnose.stats import NOISE_BINS, noise_sums
from camdegrade.effects import Noise
from camdegrade.profile import CameraProfile

#: Linearise and solve this many times.
ITERATIONS = 3
#: Each step raises a term by at most this factor (lowering is not bounded: a term may switch off).
MAX_STEP = 8.0
#: A bin takes part when it holds at least this many pixels in every set.
MIN_PIXELS = 256.0

Simulator = Callable[[CameraProfile], list[Tensor]]


@dataclass(frozen=True)
class NoiseMoments:
    """Pooled noise-level function of a set of images against their clean images: per channel and bin,
    the variance of the high-passed residual ``(3, NOISE_BINS)`` and the pixel count behind it."""

    variance: Tensor
    count: Tensor

    @classmethod
    def measure(cls, images: Sequence[Tensor], cleans: Sequence[Tensor], masks: Sequence[Tensor]) -> NoiseMoments:
        if not images:
            raise ValueError("images must hold at least one image to measure the noise level")
        num, den = torch.zeros(3 * NOISE_BINS, dtype=torch.float64), torch.zeros(3 * NOISE_BINS, dtype=torch.float64)
        for image, clean, mask in zip(images, cleans, masks, strict=True):
            n, d = noise_sums(image.float().clamp(0, 1), clean.float().clamp(0, 1), mask)
            num, den = num + n.double(), den + d.double()
        variance = torch.where(den > 0, num / den.clamp_min(1e-12), torch.zeros_like(num))
        return cls(variance.reshape(3, NOISE_BINS), den.reshape(3, NOISE_BINS))


def _with(effect: Noise, a: Tensor, b: Tensor, rows: Tensor) -> Noise:
    return Noise(
        a.clamp_min(0), b.clamp_min(0), rows.clamp_min(0), linear=effect.linear, gain_jitter=effect.gain_jitter
    )


def _references(a: Tensor, b: Tensor) -> tuple[Tensor, Tensor]:
    """Per-channel levels at which each term's response is measured: the current value, or — where a term is
    zero — a tenth of the channel's variance at a mid-dark intensity, so that the fit can switch it on."""
    level = (0.25 * a + b).clamp_min(1e-6)
    return torch.maximum(a, 0.4 * level), torch.maximum(b, 0.1 * level)


def _two_term_nnls(first: Tensor, second: Tensor, target: Tensor, weight: Tensor) -> tuple[float, float]:
    """Non-negative ``(x, y)`` minimising ``Σ w (target − x·first − y·second)²`` (2 unknowns: try the
    unconstrained solution, then each single term)."""

    def loss(x: float, y: float) -> float:
        return float((weight * (target - x * first - y * second) ** 2).sum())

    options: list[tuple[float, float]] = []
    gram = torch.tensor(
        [
            [(weight * first * first).sum(), (weight * first * second).sum()],
            [(weight * first * second).sum(), (weight * second * second).sum()],
        ],
        dtype=torch.float64,
    )
    rhs = torch.tensor([(weight * first * target).sum(), (weight * second * target).sum()], dtype=torch.float64)
    if float(torch.linalg.det(gram)) > 1e-12 * float(gram.diagonal().prod()):
        x, y = torch.linalg.solve(gram, rhs).tolist()
        if x >= 0 and y >= 0:
            options.append((x, y))
    if float(gram[0, 0]) > 0:
        options.append((max(0.0, float(rhs[0] / gram[0, 0])), 0.0))
    if float(gram[1, 1]) > 0:
        options.append((0.0, max(0.0, float(rhs[1] / gram[1, 1]))))
    if not options:
        return 1.0, 1.0
    return min(options, key=lambda option: loss(*option))


def calibrate_noise(
    effect: Noise,
    place: Callable[[Noise], CameraProfile],
    simulate_images: Simulator,
    real: NoiseMoments,
    deterministic: NoiseMoments,
    measure: Callable[[list[Tensor]], NoiseMoments],
    *,
    iterations: int = ITERATIONS,
    say: Callable[[str], None] | None = None,
) -> Noise:
    """Rescale ``effect``'s ``a`` and ``b`` (row banding with ``b``'s std) per channel so that the profile with
    it (``place(effect)``) reproduces ``real``'s noise-level function.

    Args:
        effect: the closed-form fit (the starting point; its ``linear`` and ``gain_jitter`` are kept).
        place: the profile with a noise stage inserted at its place in the chain.
        simulate_images: simulates a profile on the calibration clean images (seeded, same seed every call).
        real: the real captures' moments; ``deterministic``: the profile's own output without random stages.
        measure: the moments of simulated images (against the same clean images and masks as ``real``).
        iterations: number of linearise-and-solve steps.
    """
    if iterations < 1:
        raise ValueError(f"iterations must be at least 1, got iterations={iterations}")
    a, b = _references(effect.a.double(), effect.b.double())
    rows = _rows_with(effect.row_sigma.double(), effect.b.double(), b)
    target = real.variance - deterministic.variance
    zero = torch.zeros(3, dtype=torch.float64)
    only_a = measure(simulate_images(place(_with(effect, a, zero, zero))))
    only_b = measure(simulate_images(place(_with(effect, zero, b, rows))))
    response_a = (only_a.variance - deterministic.variance).clamp_min(0)
    response_b = (only_b.variance - deterministic.variance).clamp_min(0)
    counts = torch.stack([real.count, deterministic.count, only_a.count, only_b.count]).amin(0)
    for step in range(iterations):
        both = measure(simulate_images(place(_with(effect, a, b, rows))))
        total = (both.variance - deterministic.variance).clamp_min(0)
        summed = response_a + response_b
        share = torch.where(summed > 0, total / summed.clamp_min(1e-30), torch.ones_like(summed))
        response_a, response_b = response_a * share, response_b * share  # at (a, b), interaction shared
        scale_a, scale_b = _solve_factors(response_a, response_b, target, torch.minimum(counts, both.count), both)
        a, b, rows = a * scale_a, b * scale_b, rows * scale_b.sqrt()
        response_a, response_b = response_a * scale_a[:, None], response_b * scale_b[:, None]  # predicted
        if say is not None:
            say(
                f"    noise (simulated moments, step {step + 1}): a {_short(a)}, b {_short(b)}, "
                f"row_sigma {_short(rows)}"
            )
    return _with(effect, a.float(), b.float(), rows.float())


def _rows_with(rows: Tensor, b: Tensor, new_b: Tensor) -> Tensor:
    """Row banding moved with the constant term: its std scales with ``sqrt(b)``."""
    return torch.where(b > 0, rows * (new_b / b.clamp_min(1e-30)).sqrt(), rows)


def _solve_factors(
    response_a: Tensor, response_b: Tensor, target: Tensor, counts: Tensor, current: NoiseMoments
) -> tuple[Tensor, Tensor]:
    """Per channel, the factors ``(x, y)`` on the two terms that best match ``target`` (weighted NNLS over the
    populated bins; ``(1, 1)`` where fewer than two bins are usable)."""
    factors = []
    for channel in range(3):
        valid = (counts[channel] >= MIN_PIXELS) & (response_a[channel] + response_b[channel] > 0)
        if int(valid.sum()) < 2:
            factors.append((1.0, 1.0))
            continue
        # Var(sample variance) ∝ variance² / n: weight each bin by n / variance²
        weight = counts[channel, valid] / current.variance[channel, valid].clamp_min(1e-12) ** 2
        x, y = _two_term_nnls(response_a[channel, valid], response_b[channel, valid], target[channel, valid], weight)
        factors.append((min(x, MAX_STEP), min(y, MAX_STEP)))
    return (
        torch.tensor([f[0] for f in factors], dtype=torch.float64),
        torch.tensor([f[1] for f in factors], dtype=torch.float64),
    )


def _short(values: Tensor) -> str:
    return "/".join(f"{float(v):.3g}" for v in values)
