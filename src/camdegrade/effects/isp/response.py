"""ISP stage: the camera's luma frequency response, a gain per spatial frequency (its detail processing as a whole)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import torch
from torch import Tensor

from camdegrade.effects._fitting import as_pairs
from camdegrade.effects.base import Effect, Pairs, check_range, register_effect
from camdegrade.effects.linear import Kernel, LinearFilter
from camdegrade.functional.analysis.images import hann2d, luma
from camdegrade.functional.isp.response import frequency_response_image, knot_coordinates, response_map

__all__ = ["DEFAULT_KNOTS", "DETAIL_FROM", "LATTICE", "FrequencyResponse"]

#: Knots per axis of a new response: cells of 0.05 cycles/pixel. A phone's excess texture differs on the diagonals
#: and on the axes, so the response is a grid over (|f_y|, |f_x|), not a function of the radius (docs/results.md,
#: *Why the camera's fine detail is not learned*).
DEFAULT_KNOTS = 11
#: Below this radius (cycles/pixel) the response is 1: tone and shading are the network's, not detail.
DETAIL_FROM = 0.03
#: The 4-pixel lattice: a fitted gain at a knot on a multiple of this frequency (cycles/pixel) along both axes is at
#: most 1 (``lattice=True``). A network's or a codec's fixed pattern lives there, and amplifying it prints a grid
#: (measured with and without the cap: docs/results.md, *Why the camera's fine detail is not learned*).
LATTICE = 0.25


@register_effect
class FrequencyResponse(Effect):
    """The luma's frequency response: ``y = clip(x + (R ⊛ Y − Y), 0, 1)`` on the sRGB values ``x``, ``R`` a gain per
    spatial frequency on a ``K × K`` grid of knots over ``(|f_y|, |f_x|)`` from 0 to 0.5 cycles/pixel
    (:func:`~camdegrade.functional.isp.response.frequency_response_image`). A phone's demosaicking, sharpening and
    noise reduction together leave a texture whose spectrum no single unsharp mask reproduces; this stage takes it
    as a whole.

    Args:
        gains: ``(K, K)`` amplitude gains (default: ones, the identity), ``K`` from 2 to :attr:`MAX_KNOTS`.
        knots: ``K`` when ``gains`` is not given.

    Valid values (:meth:`check_values`): every gain from 0 to :attr:`MAX_GAIN`.

    Not a default diagnosis candidate (:attr:`Effect.candidate`): a free response can mimic any linear effect, so it
    would stand in for the blur or the sharpening the camera has rather than name it.

    References:
        R. C. Gonzalez, R. E. Woods, "Digital Image Processing", 4th ed., 2018, ch. 4 (frequency-domain filtering);
        Y. Blau, T. Michaeli, "The Perception-Distortion Tradeoff", CVPR 2018 (why it is fitted to the captures'
        power, not by least squares).
    """

    name = "frequency_response"
    stage = "isp"
    explains = ("frequency",)
    fit_budget = 16
    candidate = False
    MAX_GAIN: ClassVar[float] = 8.0
    MAX_KNOTS: ClassVar[int] = 64
    gains: Tensor

    def __init__(self, gains: Tensor | Sequence[Sequence[float]] | None = None, *, knots: int = DEFAULT_KNOTS) -> None:
        super().__init__()
        if gains is None:
            knots = _checked_knots(knots)
            values = torch.ones(knots, knots)
        else:
            values = torch.as_tensor(gains, dtype=torch.float32).clone()
            square = values.ndim == 2 and values.shape[0] == values.shape[1]
            if not square or not 2 <= values.shape[0] <= self.MAX_KNOTS:
                raise ValueError(
                    f"gains must be a square (K, K) grid with K from 2 to {self.MAX_KNOTS}, "
                    f"got shape {tuple(values.shape)}"
                )
        check_range("gains", values, 0.0, self.MAX_GAIN)
        self.register_buffer("gains", values)

    @property
    def knots(self) -> int:
        return int(self.gains.shape[-1])

    def config(self) -> dict[str, Any]:
        return {"knots": self.knots}

    def check_values(self) -> None:
        super().check_values()
        check_range("gains", self.gains, 0.0, self.MAX_GAIN)

    def scaled(self, strength: float) -> FrequencyResponse:
        """A copy whose gains are these raised to ``strength`` (0: the identity; 2: every change in log gain
        doubled), up to :attr:`MAX_GAIN`."""
        gains = self.gains.double().clamp_min(1e-6).pow(max(float(strength), 0.0)).clamp(max=self.MAX_GAIN)
        return type(self)(gains.float())

    def magnitude(self) -> float:
        """How far from the identity: the RMS over knots of ``|log2 gain|`` (1: detail doubled or halved)."""
        return float(self.gains.double().clamp_min(1e-6).log2().pow(2).mean().sqrt())

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        return frequency_response_image(image, self.gains.to(image.device))

    def linear_filter(self) -> LinearFilter:
        """A luma frequency response is linear and shift-invariant on the sRGB values: ``γ = R − δ`` on the luma
        (added to R, G and B alike), then the clamp. ``R`` has no short support (its gains are interpolated between
        knots 0.05 cycles/pixel apart), so it is given by its gains on the FFT grid, as the forward computes them."""
        gains = self.gains.detach().float().clone()

        def change(height: int, width: int) -> Tensor:
            return response_map(gains.cpu(), height, width).double() - 1.0

        return LinearFilter(luma=Kernel(spectral=change), clamps=True)

    @classmethod
    def fit(
        cls, source: Pairs, target: Pairs, *, knots: int = DEFAULT_KNOTS, lattice: bool = True
    ) -> FrequencyResponse:
        """The response that gives ``source`` the luma power spectrum of ``target``, knot by knot: the gain is
        ``2 ** (m / 2)``, ``m`` the mean over frames of ``log2(power target / power source)``, each frame's power
        summed over the frequencies nearest the knot (Hann window, mean removed); 1 below :data:`DETAIL_FROM` and,
        with ``lattice``, at most 1 on the 4-pixel lattice (:data:`LATTICE`).

        Distribution, not least squares: the pairs need not be aligned, and detail whose position the source does
        not predict (a phone's, above about 0.16 cycles/pixel: docs/results.md, *Why the camera's fine detail is not
        learned*) keeps its power instead of being shrunk away. The mean over frames of the log ratio is what the
        fidelity bands average (:func:`~camdegrade.measures.fidelity.band_log2_ratios`). Recovery on synthetic pairs
        (``tests/test_frequency_response.py``): gains within 10 % of a known smooth response, a target that is
        the source gives gains within 3 % of 1.
        """
        pairs = as_pairs(source, target)
        knots = _checked_knots(knots)
        ratios = [_knot_log_ratios(src, tgt, knots) for src, tgt in pairs]
        log_gain = 0.5 * torch.nanmean(torch.stack(ratios), 0).nan_to_num(0.0)
        gains = log_gain.exp2().clamp(1 / cls.MAX_GAIN, cls.MAX_GAIN)
        return cls(_detail_only(gains, lattice).float())

    @classmethod
    def from_radial(
        cls, radii: Sequence[float], gains: Sequence[float], *, knots: int = DEFAULT_KNOTS, lattice: bool = True
    ) -> FrequencyResponse:
        """A response that depends on the radius of the frequency alone: amplitude ``gains`` at ``radii``
        (cycles/pixel, increasing), the log gain interpolated linearly in log radius between them and constant
        beyond the first and the last; 1 below :data:`DETAIL_FROM` and, with ``lattice``, at most 1 on the 4-pixel
        lattice (:data:`LATTICE`). What a set-level spectrum match can fit (:mod:`camdegrade.fitting.unpaired`):
        a grid of knots over ``(|f_y|, |f_x|)`` needs pairs."""
        knots = _checked_knots(knots)
        at, values = _finite_numbers("radii", radii), _finite_numbers("gains", gains)
        if at.ndim != 1 or at.shape != values.shape or len(at) < 2 or not bool((at[1:] > at[:-1]).all()):
            raise ValueError(
                f"radii must be at least two increasing frequencies with one gain each, got radii={at.tolist()} "
                f"and gains={values.tolist()}"
            )
        if not bool(at[0] > 0):
            raise ValueError(f"radii must be above 0 cycles/pixel, got radii={at.tolist()}")
        if not bool((values > 0).all() & (values <= cls.MAX_GAIN).all()):
            raise ValueError(f"gains must be above 0 and at most {cls.MAX_GAIN:g}, got gains={values.tolist()}")
        log_gains = values.log2()
        index = torch.arange(knots, dtype=torch.float64) * (0.5 / (knots - 1))
        radius = (index[:, None] ** 2 + index[None, :] ** 2).sqrt().clamp(float(at[0]), float(at[-1]))
        position = torch.log(radius)
        upper = torch.searchsorted(torch.log(at), position).clamp(1, len(at) - 1)
        lower = upper - 1
        share = (position - torch.log(at[lower])) / (torch.log(at[upper]) - torch.log(at[lower]))
        log_gain = log_gains[lower] + share * (log_gains[upper] - log_gains[lower])
        return cls(_detail_only(log_gain.exp2(), lattice).float())


def _checked_knots(knots: Any) -> int:
    """``knots`` as an int, or ``ValueError`` naming it unless it is a whole number from 2 to ``MAX_KNOTS``."""
    whole = not isinstance(knots, bool) and isinstance(knots, (int, float)) and float(knots).is_integer()
    if not whole or not 2 <= knots <= FrequencyResponse.MAX_KNOTS:
        raise ValueError(f"knots must be an integer from 2 to {FrequencyResponse.MAX_KNOTS}, got knots={knots!r}")
    return int(knots)


def _finite_numbers(name: str, values: Any) -> Tensor:
    """``values`` as a float64 tensor; ``TypeError`` naming ``name`` unless they are numbers, ``ValueError`` unless
    every one is finite."""
    try:
        out = torch.as_tensor(values, dtype=torch.float64)
    except (TypeError, ValueError, RuntimeError):
        raise TypeError(f"{name} must be a sequence of numbers, got {name}={values!r}") from None
    if not bool(torch.isfinite(out).all()):
        raise ValueError(f"{name} must be finite, got {name}={out.tolist()}")
    return out


def _detail_only(gains: Tensor, lattice: bool) -> Tensor:
    """``(K, K)`` knot ``gains`` set to 1 below :data:`DETAIL_FROM` and, with ``lattice``, capped at 1 on the
    4-pixel lattice (:data:`LATTICE`)."""
    gains = gains.clone()
    knots = gains.shape[-1]
    step = 0.5 / (knots - 1)
    index = torch.arange(knots, dtype=torch.float64) * step
    radius = (index[:, None] ** 2 + index[None, :] ** 2).sqrt()
    gains[radius < DETAIL_FROM] = 1.0
    if lattice:
        on_lattice = _on_lattice(index, step)
        capped = on_lattice[:, None] & on_lattice[None, :] & (radius > 0)
        gains[capped] = gains[capped].clamp(max=1.0)
    return gains


def _on_lattice(frequencies: Tensor, step: float) -> Tensor:
    """Which knots are the ones nearest a multiple of :data:`LATTICE` cycles/pixel."""
    nearest = (frequencies / LATTICE).round() * LATTICE
    return (frequencies - nearest).abs() < step / 2


def _knot_log_ratios(source: Tensor, target: Tensor, knots: int) -> Tensor:
    """``(K, K)``: ``log2`` of the target's luma power over the source's per knot (NaN where either has none)."""
    ratio = _knot_powers(target, knots) / _knot_powers(source, knots)
    return torch.where(torch.isfinite(ratio) & (ratio > 0), ratio.log2(), math.nan)


def _knot_powers(image: Tensor, knots: int) -> Tensor:
    """``(K, K)`` luma power of the ``(3, H, W)`` frame (Hann window, mean removed) summed over the frequencies
    nearest each knot."""
    gray = luma(image.double())
    gray = gray - gray.mean()
    height, width = gray.shape
    power = torch.fft.rfft2(gray * hann2d(height, width, dtype=torch.float64)).abs().pow(2)
    rows = knot_coordinates(height, knots, half=False).round().long()
    cols = knot_coordinates(width, knots, half=True).round().long()
    cell = (rows[:, None] * knots + cols[None, :]).flatten()
    return torch.bincount(cell, weights=power.flatten(), minlength=knots * knots).view(knots, knots)
