"""Linear shift-invariant stages as filters: what such a stage is (:class:`LinearFilter`, the fact
:meth:`~camdegrade.effects.base.Effect.linear_filter` states), how adjacent ones compose into one, and how a
composed filter runs.

A filter acts on the values of one encoding as ``y = α ⊛ (x + (γ ⊛ Y)·1)``: the kernel ``α`` filters every channel
alike; ``γ`` filters the luma ``Y`` (Rec. 601) and adds the result to R, G and B alike, as a phone's detail
processing does. A blur is ``(α = PSF, γ = 0)``, unsharp masking of the luma ``(δ, a·(δ − G))``, a luma frequency
response ``(δ, R − δ)``. Two such filters compose into one of the same form, because convolutions commute:
``(α₁, γ₁)`` then ``(α₂, γ₂)`` is ``(α₂ ⊛ α₁, γ₁ + γ₂ + s·γ₂ ⊛ γ₁)``, ``s`` the sum of the luma weights (1). The
composed filter runs as ``y = α ⊛ x``, then ``y += (γ ⊛ Y(y))·1`` (``Y(α ⊛ x) = α ⊛ Y(x)``), each kernel where it
is cheapest: a short kernel as separable shifted sums, one without short support as one product of spectra.

A kernel is ``identity · δ`` plus separable terms (exact: the PSFs and unsharp masks here are sums of separable
Gaussians, and the convolution of two separable terms is separable), plus, where it has no short support (a
frequency response), its gains on the FFT grid.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade.functional.analysis.images import LUMA_WEIGHTS
from camdegrade.functional.filtering import SeparableTerm, convolve_spectrum, convolve_terms, luma_plane, terms_radius

__all__ = [
    "DELTA",
    "NEGLIGIBLE_TAP",
    "SPECTRUM_PAD",
    "ZERO",
    "Encoding",
    "Gains",
    "Kernel",
    "LinearFilter",
    "gaussian_term",
    "taps_kernel",
]

#: How float values encode light: sRGB-encoded (what images hold) or linear light (what sensors and lenses act on).
Encoding = Literal["srgb", "linear"]

#: Gains of a kernel on the ``rfft2`` grid of an ``h × w`` frame (complex128 ``(h, w // 2 + 1)``).
Gains = Callable[[int, int], Tensor]
#: Rows and columns of mirrored border before a product of spectra (as :mod:`camdegrade.functional.isp.response`).
SPECTRUM_PAD = 16
#: Taps lighter than this are left out of a composed term (each term's taps sum to at most a few units): they move
#: no output by a measurable fraction of an 8-bit level.
NEGLIGIBLE_TAP = 1e-9


@dataclass(frozen=True)
class Kernel:
    """A 2-D convolution kernel: ``identity`` times the unit impulse, plus separable ``terms`` (each a weight and its
    taps down and across, odd counts, centred), plus ``spectral`` gains for a part without short support (e.g. a
    frequency response; ``None`` when there is none)."""

    identity: float = 0.0
    terms: tuple[SeparableTerm, ...] = ()
    spectral: Gains | None = field(default=None, compare=False)

    @property
    def is_zero(self) -> bool:
        return self.identity == 0.0 and not self.terms and self.spectral is None

    @property
    def is_identity(self) -> bool:
        return self.identity == 1.0 and not self.terms and self.spectral is None

    def radius(self) -> int:
        """The largest half-length of the separable taps (0 for none)."""
        return max(terms_radius(self.terms))

    @property
    def mirror_symmetric(self) -> bool:
        """Whether the kernel is finite and symmetric about both axes (every term's taps read the same backwards):
        then it keeps an image's mirrored border mirrored, so a later filter reading that border reads what it
        would read after this one alone."""
        return self.spectral is None and all(_palindrome(d) and _palindrome(a) for _, d, a in self.terms)

    def plus(self, other: Kernel) -> Kernel:
        spectral = _sum_gains(self.spectral, other.spectral)
        return Kernel(self.identity + other.identity, _merged(self.terms + other.terms), spectral)

    def times(self, factor: float) -> Kernel:
        spectral = None if self.spectral is None else _scaled_gains(self.spectral, factor)
        return Kernel(self.identity * factor, _merged(tuple((w * factor, d, a) for w, d, a in self.terms)), spectral)

    def convolved(self, other: Kernel) -> Kernel:
        """This kernel convolved with ``other`` (exact: separable terms convolve term by term)."""
        if self.spectral is not None or other.spectral is not None:
            return Kernel(spectral=_product_gains(self.gains, other.gains))
        terms = [(w * other.identity, d, a) for w, d, a in self.terms]
        terms += [(w * self.identity, d, a) for w, d, a in other.terms]
        terms += [
            (w1 * w2, _convolved(d1, d2), _convolved(a1, a2)) for w1, d1, a1 in self.terms for w2, d2, a2 in other.terms
        ]
        return Kernel(self.identity * other.identity, _merged(tuple(terms)))

    def gains(self, height: int, width: int) -> Tensor:
        """The kernel's gain at every ``rfft2`` frequency of a ``height × width`` frame (its taps wrapped round the
        origin), complex128 ``(height, width // 2 + 1)``."""
        total = torch.full((height, width // 2 + 1), self.identity, dtype=torch.complex128)
        for weight, down, across in self.terms:
            total += weight * _taps_gains(down, height, full=True)[:, None] * _taps_gains(across, width, full=False)
        if self.spectral is not None:
            total += self.spectral(height, width)
        return total

    def apply(self, planes: Tensor, cache: dict[tuple, Tensor] | None = None) -> Tensor:
        """``planes`` ``(N, C, H, W)`` float convolved with this kernel (a new tensor, or ``planes`` itself for the
        identity): the separable part by shifted sums, a spectral part by one product of spectra (mirrored border
        of :data:`SPECTRUM_PAD`, at least the separable radius, at most the size less one), its gains kept in
        ``cache`` (the caller's, one per kernel) for the last frame size, dtype and device."""
        if self.is_identity:
            return planes
        if self.spectral is None:
            return convolve_terms(planes, self.identity, self.terms)
        height, width = planes.shape[-2:]
        pad = min(max(SPECTRUM_PAD, self.radius()), height - 1, width - 1)
        cache = {} if cache is None else cache

        def gains(h: int, w: int) -> Tensor:
            key = (h, w, planes.dtype, planes.device)
            if key not in cache:
                cache.clear()  # a transform sees few sizes, and a rebuild costs less than a call
                complex_dtype = torch.complex128 if planes.dtype == torch.float64 else torch.complex64
                cache[key] = self.gains(h, w).to(planes.device, complex_dtype)
            return cache[key]

        return convolve_spectrum(planes, gains, pad)


DELTA = Kernel(identity=1.0)
ZERO = Kernel()


@dataclass(frozen=True)
class LinearFilter:
    """A linear shift-invariant filter of the values in one ``encoding``: ``y = α ⊛ (x + (γ ⊛ Y)·1)`` with
    ``α = own`` and ``γ = luma`` (see the module), clamped to [0, 1] afterwards when ``clamps``.

    A stage that clamps ends a run of composed filters (the clamp is not linear); :meth:`then` refuses to compose
    past it."""

    own: Kernel = DELTA
    luma: Kernel = ZERO
    encoding: Encoding = "srgb"
    clamps: bool = False

    @property
    def is_identity(self) -> bool:
        return self.own.is_identity and self.luma.is_zero and not self.clamps

    def composes_with(self, later: LinearFilter) -> bool:
        """Whether ``later`` may follow this filter in one composed filter with the same output, borders included:
        one encoding, no clamp in between, and this filter's kernels finite and mirror-symmetric (a stage reads
        its input's border mirrored; the composed filter mirrors the first input only, which is the same only if
        what ran before keeps a mirrored border mirrored; a rotated PSF does not: up to 15 levels at the border of a
        200×220 photo, measured)."""
        return (
            not self.clamps
            and later.encoding == self.encoding
            and self.own.mirror_symmetric
            and self.luma.mirror_symmetric
        )

    def then(self, later: LinearFilter) -> LinearFilter:
        """This filter followed by ``later`` as one filter (:meth:`composes_with` must hold)."""
        if not self.composes_with(later):
            raise ValueError("this filter does not compose with the later one (see LinearFilter.composes_with)")
        luma = self.luma.plus(later.luma).plus(later.luma.convolved(self.luma).times(sum(LUMA_WEIGHTS)))
        return LinearFilter(later.own.convolved(self.own), luma, self.encoding, later.clamps)

    def radius(self) -> int:
        """How far a pixel's output reads its neighbours through the separable parts."""
        return self.own.radius() + self.luma.radius()

    def run_(self, image: Tensor, caches: tuple[dict, dict] | None = None) -> Tensor:
        """The filter on float ``image`` ``(N, 3, H, W)`` in :attr:`encoding`, which the caller owns (it may be
        overwritten and returned); ``caches`` keep the two kernels' spectral gains between calls."""
        own_cache, luma_cache = ({}, {}) if caches is None else caches
        out = self.own.apply(image, own_cache)
        if not self.luma.is_zero:
            out = out.add_(self.luma.apply(luma_plane(out), luma_cache))
        return out.clamp_(0.0, 1.0) if self.clamps else out


def gaussian_term(taps: Tensor, weight: float = 1.0) -> SeparableTerm:
    """A separable term from 1-D taps ``(K,)`` used down and across (an isotropic Gaussian)."""
    values = tuple(float(t) for t in taps.double().flatten())
    return (float(weight), values, values)


def taps_kernel(taps: Tensor) -> Kernel:
    """A 2-D kernel ``(K, K)`` (odd, centred) as separable terms: its singular value decomposition in float64, terms
    kept until what is left weighs less than :data:`NEGLIGIBLE_TAP` in all (a Gaussian PSF is one term)."""
    values = taps.double()
    u, s, vh = torch.linalg.svd(values)
    terms = []
    for index in range(len(s)):
        residual = values - (u[:, : index + 1] * s[: index + 1]) @ vh[: index + 1]
        terms.append((float(s[index]), tuple(u[:, index].tolist()), tuple(vh[index].tolist())))
        if float(residual.abs().sum()) < NEGLIGIBLE_TAP:
            break
    return Kernel(terms=tuple(terms))


def _convolved(first: tuple[float, ...], second: tuple[float, ...]) -> tuple[float, ...]:
    """The full 1-D convolution of two centred odd tap lists (centred, odd)."""
    a = torch.tensor(first, dtype=torch.float64).view(1, 1, -1)
    b = torch.tensor(second, dtype=torch.float64).flip(0).view(1, 1, -1)
    values = F.conv1d(a, b, padding=len(second) - 1).flatten()
    return tuple(values.tolist())


def _palindrome(taps: tuple[float, ...]) -> bool:
    return all(abs(a - b) <= 1e-12 * max(1.0, abs(a)) for a, b in zip(taps, reversed(taps), strict=True))


def _merged(terms: tuple[SeparableTerm, ...]) -> tuple[SeparableTerm, ...]:
    """Terms with the same taps added, zero weights dropped, outer taps lighter than :data:`NEGLIGIBLE_TAP` in both
    directions trimmed."""
    weights: dict[tuple[tuple[float, ...], tuple[float, ...]], float] = {}
    for weight, down, across in terms:
        key = (_trimmed(down), _trimmed(across))
        weights[key] = weights.get(key, 0.0) + weight
    return tuple((weight, down, across) for (down, across), weight in weights.items() if weight != 0.0)


def _trimmed(taps: tuple[float, ...]) -> tuple[float, ...]:
    cut = 0
    while len(taps) - 2 * cut > 1 and max(abs(taps[cut]), abs(taps[-1 - cut])) < NEGLIGIBLE_TAP:
        cut += 1
    return taps[cut : len(taps) - cut]


def _taps_gains(taps: tuple[float, ...], size: int, *, full: bool) -> Tensor:
    """The DFT (``full``) or real DFT of centred taps wrapped round index 0 of a line of ``size``."""
    line = torch.zeros(size, dtype=torch.float64)
    radius = len(taps) // 2
    for offset, tap in zip(range(-radius, radius + 1), taps, strict=True):
        line[offset % size] += tap
    return torch.fft.fft(line) if full else torch.fft.rfft(line)


def _sum_gains(first: Gains | None, second: Gains | None) -> Gains | None:
    if first is None or second is None:
        return first if second is None else second
    return lambda h, w: first(h, w) + second(h, w)


def _scaled_gains(gains: Gains, factor: float) -> Gains:
    return lambda h, w: gains(h, w) * factor


def _product_gains(first: Gains, second: Gains) -> Gains:
    return lambda h, w: first(h, w) * second(h, w)
