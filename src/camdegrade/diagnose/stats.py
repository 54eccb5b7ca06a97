"""Signature statistics of a camera's degradation, their null bands, and the one scalar sim-to-real gap.

Every **paired** statistic is measured on an image ``x`` (a real capture, or the profile's simulation) *against
the clean image* ``c`` it came from. Real and simulated sets share their clean images, so content cancels when
the two are compared and a small difference is significant. Each statistic is kept per pair as sums
(``num``, ``den``), so the set's value (sums over pairs, then :attr:`Family.reduce`) can be recomputed on any
bootstrap resample of the pairs in microseconds.

The families, and what each localises (the axis names of the report's ``where``):

======================  ================================================================  =====================
family (axis)           statistic                                                        unit of one ``tau``
======================  ================================================================  =====================
``spatial``             mean of ``x − c`` on an 8×8 grid of tiles, per channel            1 level (of 255)
``intensity``           mean of low-passed ``x − c`` in 16 bins of clean value, per ch.   1 level
``noise``               std of ``x`` minus its 17×17 mean where ``c`` is flat in        0.05 (5 %)
                        absolute terms, 8 bins of clean value, compared as log std
``noise_correlation``   that residual's correlation at lags 1, 2 (horizontal, vertical)   0.05
                        per channel, and between the channels (chroma noise)
``banding``             std of the residual's per-row and per-column means (flat         0.05 (5 %)
                        pixels), per channel, compared as log std
``frequency``           transfer function Re(X·C*)/|C|² in 8 radial bands (luma),        0.02
                        relative to the lowest band (a blur/sharpening MTF)
``blocks``              luma gradient energy at each of the 8 column/row phases of the   0.01
                        8×8 grid, relative to the mean (JPEG blocking)
``color``               3×3 linear-light least-squares matrix ``x ≈ M c`` (low-passed)   0.01
``alignment``           per-tile (4×4), per-channel displacement of ``x`` against ``c``  0.05 pixel
                        (Lucas–Kanade with a per-tile affine intensity map projected out)
======================  ================================================================  =====================

The transfer function and the displacements are cross-statistics with the clean image, so independent noise
averages out of them; the noise family compares noise levels, not noise samples. That is what makes the gap
fair to stochastic effects: a correct noise stage does not increase it (see ``docs/diagnosis.md``).

The gap between two sets is ``Σ_families RMS_k((value_k(real) − value_k(sim)) / tau_family)``: each family
contributes the root-mean-square of its components' differences in units of ``tau`` (noise levels differenced
as log std, :attr:`Family.compare`), so one family off by one ``tau`` everywhere adds 1. Components without
enough data (an empty intensity bin) are left out.

References:
    B. D. Lucas, T. Kanade, "An iterative image registration technique with an application to stereo vision",
    IJCAI 1981 (the per-tile displacement of the ``alignment`` family).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade.functional import srgb_to_linear
from camdegrade.functional.analysis import box_mean, flat_mask, hann2d, luma
from camdegrade.functional.noise_stats import MIN_LINES, MIN_PIXELS, NoiseSums

TILES = 8
SHIFT_TILES = 4
INTENSITY_BINS = 16
NOISE_BINS = 8
BANDS = 8
_MIN_COUNT = 64.0
#: A component missing (too few pixels) from more than this share of the bootstrap resamples is left out.
MAX_MISSING = 0.1


def _ratio(num: Tensor, den: Tensor) -> Tensor:
    return torch.where(den > 0, num / den.clamp_min(1e-12), torch.full_like(num, float("nan")))


def _ratio_min_count(num: Tensor, den: Tensor) -> Tensor:
    return torch.where(den >= _MIN_COUNT, num / den.clamp_min(1e-12), torch.full_like(num, float("nan")))


def _levels(num: Tensor, den: Tensor) -> Tensor:
    """Mean of a difference in [0, 1] units → 8-bit levels."""
    return _ratio_min_count(num, den) * 255.0


def _mean_levels(num: Tensor, den: Tensor) -> Tensor:
    return _ratio(num, den) * 255.0


def _noise_std(num: Tensor, den: Tensor) -> Tensor:
    """Sums of squared residuals (levels²) and flat-pixel counts → std in levels; NaN below MIN_PIXELS."""
    return torch.where(den >= MIN_PIXELS, num / den.clamp_min(1), torch.nan).sqrt()


def _correlations(num: Tensor, den: Tensor) -> Tensor:
    """Products and energies → correlations (lags, then channel pairs); all NaN where the flat pixels behind them
    (the last component) are too few."""
    values = _ratio(num[..., :-1], den[..., :-1])
    return torch.where(num[..., -1:] >= MIN_PIXELS, values, torch.nan)


def _line_std(num: Tensor, den: Tensor) -> Tensor:
    """Sums of squared line means and line counts → std in levels; NaN below MIN_LINES lines."""
    return torch.where(den >= MIN_LINES, num / den.clamp_min(1), torch.nan).sqrt()


def _relative_mtf(num: Tensor, den: Tensor) -> Tensor:
    h = _ratio(num, den)
    return h[..., 1:] / h[..., :1]


def _color_matrix(num: Tensor, den: Tensor) -> Tensor:
    xc = num.reshape(*num.shape[:-1], 3, 3).double()
    cc = den.reshape(*den.shape[:-1], 3, 3).double()
    ridge = 1e-9 * torch.eye(3, dtype=torch.float64)
    matrix = torch.linalg.solve(cc + ridge, xc.transpose(-1, -2)).transpose(-1, -2)
    return matrix.flatten(-2).float()


def _displacement(num: Tensor, den: Tensor) -> Tensor:
    """Solve the summed per-tile normal equations of ``e ≈ α + β c − d·∇c`` and return ``d`` in pixels."""
    b = num.double()  # (..., T, 3, 4)
    a = den.double().reshape(*den.shape[:-1], 4, 4)
    scale = a.diagonal(dim1=-2, dim2=-1).mean(-1, keepdim=True)[..., None].clamp_min(1e-12)
    solution = torch.linalg.solve(a + 1e-6 * scale * torch.eye(4, dtype=torch.float64), b[..., None])[..., 0]
    texture = a[..., 2, 2] + a[..., 3, 3]
    shift = -solution[..., 2:]
    weak = texture < 1e-3 * texture.flatten().max().clamp_min(1e-12)
    shift = torch.where(weak[..., None], torch.full_like(shift, float("nan")), shift)
    return shift.flatten(-3).float()


def _same(values: Tensor) -> Tensor:
    return values


#: Noise levels are compared as ``log sqrt(std² + floor²)``: a noise level is a scale, and a 1-level miss
#: matters at std 2 and not at std 30. The floor (0.5 level, above 8-bit quantisation's 0.29) keeps a missing
#: noise stage finite.
NOISE_FLOOR = 0.5


def _log_level(std: Tensor) -> Tensor:
    return 0.5 * torch.log(std.pow(2) + NOISE_FLOOR**2)


#: Line means are a small part of the noise (0.3 levels on real captures): their floor is lower.
LINE_FLOOR = 0.1


def _log_line(std: Tensor) -> Tensor:
    return 0.5 * torch.log(std.pow(2) + LINE_FLOOR**2)


@dataclass(frozen=True)
class Family:
    """One statistic family: its unit ``tau`` (the difference worth one gap unit), how sums become values and
    the scale (``compare``) on which real and simulated values are differenced."""

    name: str
    tau: float
    reduce: Callable[[Tensor, Tensor], Tensor]
    unit: str
    compare: Callable[[Tensor], Tensor] = _same


FAMILIES: dict[str, Family] = {
    family.name: family
    for family in (
        Family("spatial", 1.0, _mean_levels, "8-bit levels"),
        Family("intensity", 1.0, _levels, "8-bit levels"),
        Family("noise", 0.05, _noise_std, "8-bit levels (std); compared as log std, tau 5 %", _log_level),
        Family("noise_correlation", 0.05, _correlations, "correlation"),
        Family("banding", 0.05, _line_std, "8-bit levels (std of line means); compared as log std", _log_line),
        Family("frequency", 0.02, _relative_mtf, "transfer ratio"),
        Family("blocks", 0.01, _ratio, "relative gradient energy"),
        Family("color", 0.01, _color_matrix, "matrix entry"),
        Family("alignment", 0.05, _displacement, "pixels"),
    )
}


def _spatial(x: Tensor, c: Tensor) -> tuple[Tensor, Tensor]:
    tiles = min(TILES, *c.shape[-2:])
    num = F.adaptive_avg_pool2d((x - c)[None], tiles)[0]
    if tiles < TILES:
        num = F.interpolate(num[None], size=(TILES, TILES), mode="nearest")[0]
    return num.flatten(), torch.ones(num.numel())


def _low(image: Tensor, factor: int = 4) -> Tensor:
    if min(image.shape[-2:]) < 4 * factor:
        return image
    return F.avg_pool2d(image[None], factor)[0]


def _intensity(x: Tensor, c: Tensor) -> tuple[Tensor, Tensor]:
    low_x, low_c = _low(x), _low(c)
    key = (low_c * INTENSITY_BINS).long().clamp(0, INTENSITY_BINS - 1) + torch.arange(3)[:, None, None] * (
        INTENSITY_BINS
    )
    size = 3 * INTENSITY_BINS
    num = torch.bincount(key.flatten(), weights=(low_x - low_c).flatten().double(), minlength=size)
    den = torch.bincount(key.flatten(), minlength=size).double()
    return num.float(), den.float()


def noise_family_sums(x: Tensor, c: Tensor, mask: Tensor) -> dict[str, tuple[Tensor, Tensor]]:
    """The ``noise``, ``noise_correlation`` and ``banding`` families' per-pair sums, from the image's own noise on
    the pixels where the clean image is flat (:class:`~camdegrade.functional.noise_stats.NoiseSums`)."""
    sums = NoiseSums.measure(x, c, mask)
    products, first, second, _ = sums.lag.unbind(-1)
    cross = sums.cross
    pairs = [(0, 1), (0, 2), (1, 2)]
    correlation_num = torch.cat([products.flatten(), torch.stack([cross[i, j] for i, j in pairs])])
    energies = torch.cat(
        [((first + second) / 2).flatten(), torch.stack([(cross[i, i] + cross[j, j]) / 2 for i, j in pairs])]
    )
    pixels = sums.count.sum(1).max()
    return {
        "noise": (sums.square.flatten().float(), sums.count.flatten().float()),
        "noise_correlation": (
            torch.cat([correlation_num, pixels[None]]).float(),
            torch.cat([energies, torch.ones(1, dtype=energies.dtype)]).float(),
        ),
        "banding": (sums.lines[..., 0].flatten().float(), sums.lines[..., 2].flatten().float()),
    }


def _band_index(height: int, width: int) -> Tensor:
    fy = torch.fft.fftfreq(height)[:, None]
    fx = torch.fft.rfftfreq(width)[None, :]
    radius = torch.sqrt(fy**2 + fx**2)
    band = (radius / 0.5 * BANDS).long().clamp(max=BANDS - 1)
    return torch.where(radius < 1.0 / max(height, width), torch.full_like(band, -1), band)


def _frequency(x: Tensor, c: Tensor) -> tuple[Tensor, Tensor]:
    height, width = c.shape[-2:]
    window = hann2d(height, width)
    lx, lc = luma(x), luma(c)
    spectrum_x = torch.fft.rfft2((lx - lx.mean()) * window)
    spectrum_c = torch.fft.rfft2((lc - lc.mean()) * window)
    cross = (spectrum_x * spectrum_c.conj()).real
    power = spectrum_c.abs().pow(2)
    band = _band_index(height, width)
    valid = band >= 0
    num = torch.bincount(band[valid], weights=cross[valid].double(), minlength=BANDS)
    den = torch.bincount(band[valid], weights=power[valid].double(), minlength=BANDS)
    scale = float(height * width)
    return (num / scale).float(), (den / scale).float()


def _blocks(x: Tensor, c: Tensor) -> tuple[Tensor, Tensor]:
    gray = luma(x)
    gx = (gray[:, 1:] - gray[:, :-1]).abs()
    gy = (gray[1:, :] - gray[:-1, :]).abs()
    out = []
    for grad, axis in ((gx, 1), (gy, 0)):
        length = grad.shape[axis] // 8 * 8
        if length < 8:
            out.append(torch.zeros(8))
            continue
        trimmed = grad[:, :length] if axis == 1 else grad[:length, :]
        profile = trimmed.mean(1 - axis).reshape(-1, 8).mean(0)
        out.append(profile)
    num = torch.cat(out)
    den = torch.cat([o.mean().expand(8) for o in out])
    return num, den


def _color(x: Tensor, c: Tensor) -> tuple[Tensor, Tensor]:
    low_x = srgb_to_linear(_low(x)).reshape(3, -1).double()
    low_c = srgb_to_linear(_low(c)).reshape(3, -1).double()
    usable = ((low_c > 0.002) & (low_c < 0.9)).all(0) & ((low_x > 0.001) & (low_x < 0.95)).all(0)
    low_x, low_c = low_x[:, usable], low_c[:, usable]
    scale = float(max(1, low_c.shape[1]))
    return (low_x @ low_c.T / scale).flatten().float(), (low_c @ low_c.T / scale).flatten().float()


def _alignment(x: Tensor, c: Tensor) -> tuple[Tensor, Tensor]:
    factor = 2 if min(c.shape[-2:]) >= 192 else 1  # large images: half resolution, gradients per full pixel
    if factor > 1:
        smooth_x, smooth_c = F.avg_pool2d(x[None], factor)[0], F.avg_pool2d(c[None], factor)[0]
    else:
        smooth_x, smooth_c = box_mean(x, 3), box_mean(c, 3)
    gx = (F.pad(smooth_c[..., :, 2:] - smooth_c[..., :, :-2], (1, 1), mode="replicate")) / (2 * factor)
    gy = (F.pad(smooth_c[..., 2:, :] - smooth_c[..., :-2, :], (0, 0, 1, 1), mode="replicate")) / (2 * factor)
    error = smooth_x - smooth_c
    design = torch.stack([torch.ones_like(smooth_c), smooth_c, gx, gy], 1)  # (3, 4, H, W)
    height, width = smooth_c.shape[-2:]
    border = max(2, min(height, width) // 32)
    design = design[..., border : height - border, border : width - border]
    error = error[..., border : height - border, border : width - border]
    tiles = min(SHIFT_TILES, *design.shape[-2:])
    products = (design[:, :, None] * design[:, None, :]).reshape(3, 16, *design.shape[-2:])
    den = F.adaptive_avg_pool2d(products, tiles)  # (3, 16, T, T)
    num = F.adaptive_avg_pool2d(design * error[:, None], tiles)  # (3, 4, T, T)
    den = den.permute(2, 3, 0, 1).reshape(tiles * tiles, 3, 16)
    num = num.permute(2, 3, 0, 1).reshape(tiles * tiles, 3, 4)
    return num, den


_MEASURES: dict[str, Callable[..., tuple[Tensor, Tensor]]] = {
    "spatial": _spatial,
    "intensity": _intensity,
    "frequency": _frequency,
    "blocks": _blocks,
    "color": _color,
    "alignment": _alignment,
}


def pair_statistics(image: Tensor, clean: Tensor, mask: Tensor | None = None) -> dict[str, tuple[Tensor, Tensor]]:
    """Every family's sums for one image ``(3, H, W)`` against its clean image, float in [0, 1]; ``mask`` is the
    clean image's :func:`~camdegrade.functional.analysis.flat_mask` (computed when not given)."""
    image, clean = image.float().clamp(0, 1), clean.float().clamp(0, 1)
    out = {name: measure(image, clean) for name, measure in _MEASURES.items()}
    out.update(noise_family_sums(image, clean, flat_mask(clean) if mask is None else mask))
    return {name: out[name] for name in FAMILIES}


@dataclass
class StatisticSet:
    """Per-pair sums of every family for a set of images measured against the same clean images."""

    sums: dict[str, tuple[Tensor, Tensor]]

    @classmethod
    def measure(cls, images: Sequence[Tensor], cleans: Sequence[Tensor], masks: Sequence[Tensor]) -> StatisticSet:
        per_pair = [pair_statistics(x, c, m) for x, c, m in zip(images, cleans, masks, strict=True)]
        if not per_pair:
            raise ValueError("images must hold at least one image to measure statistics")
        return cls(
            {
                name: (torch.stack([p[name][0] for p in per_pair]), torch.stack([p[name][1] for p in per_pair]))
                for name in FAMILIES
            }
        )

    def __len__(self) -> int:
        return next(iter(self.sums.values()))[0].shape[0]

    def values(self, index: Tensor | None = None) -> dict[str, Tensor]:
        """Each family's statistic over the pairs (all, or the resample ``index``)."""
        out = {}
        for name, family in FAMILIES.items():
            num, den = self.sums[name]
            if index is not None:
                num, den = num[index], den[index]
            out[name] = family.reduce(num.double().sum(0), den.double().sum(0)).flatten().float()
        return out

    def flat_pixels(self) -> int:
        """Pixels (per channel, the most any channel has) the noise families rest on, over every pair."""
        return int(self.sums["noise"][1].double().sum(0).reshape(3, -1).sum(1).max())

    def lines(self) -> tuple[int, int]:
        """Rows and columns (channel 0) the banding family rests on, over every pair."""
        counts = self.sums["banding"][1].double().sum(0).reshape(2, 3)
        return int(counts[0, 0]), int(counts[1, 0])

    def compared(self, index: Tensor | None = None) -> dict[str, Tensor]:
        """:meth:`values` on the scale they are compared on (:attr:`Family.compare`)."""
        return {name: FAMILIES[name].compare(value) for name, value in self.values(index).items()}


Scale = dict[str, Tensor]


def family_gaps(
    real: StatisticSet, sim: StatisticSet, index: Tensor | None = None, scale: Scale | None = None
) -> dict[str, float]:
    """Per family, the RMS of ``(real − sim) / scale`` over the components both sets can measure; ``scale``
    defaults to ``tau`` (see :func:`measurement_scale`)."""
    real_values, sim_values = real.compared(index), sim.compared(index)
    out = {}
    for name, family in FAMILIES.items():
        unit = scale[name] if scale is not None else family.tau
        diff = (real_values[name] - sim_values[name]) / unit
        diff = diff[torch.isfinite(diff)]
        out[name] = float(diff.pow(2).mean().sqrt()) if diff.numel() else 0.0
    return out


def gap(real: StatisticSet, sim: StatisticSet, index: Tensor | None = None, scale: Scale | None = None) -> float:
    """The scalar sim-to-real gap: the sum of :func:`family_gaps`."""
    return sum(family_gaps(real, sim, index, scale).values())


def measurement_scale(real: StatisticSet, sim: StatisticSet, indices: Tensor) -> Scale:
    """Per component, ``sqrt(tau² + SE²)``: SE is the bootstrap standard error (over pairs) of the difference
    ``real − sim``. Statistics that the real data cannot pin down (a transfer ratio in a band where the content
    has little power, a noise bin with few pixels) then count for less. Computed once, against the profile as
    it is, and used as the fixed yardstick for every candidate and for the noise floor.

    A component that cannot be measured on more than :data:`MAX_MISSING` of the resamples rests on one or two
    pairs (an intensity bin only one image populates): its bootstrap spread is meaningless (near zero where it
    is measured) and it would enter and leave the gap from resample to resample. Its scale is NaN, which leaves
    it out of every gap."""
    rounds = []
    for index in indices:
        r, s = real.compared(index), sim.compared(index)
        rounds.append({name: r[name] - s[name] for name in FAMILIES})
    out = {}
    for name, family in FAMILIES.items():
        stacked = torch.stack([entry[name] for entry in rounds])
        finite = torch.isfinite(stacked)
        count = finite.sum(0).clamp_min(2)
        mean = torch.where(finite, stacked, 0).sum(0) / count
        variance = torch.where(finite, (stacked - mean) ** 2, 0).sum(0) / (count - 1)
        supported = finite.double().mean(0) >= 1.0 - MAX_MISSING
        out[name] = torch.where(supported, (family.tau**2 + variance).sqrt(), float("nan"))
    return out


def bootstrap_indices(count: int, rounds: int, seed: int) -> Tensor:
    """``(rounds, count)`` resamples of ``range(count)`` with replacement, from a seeded generator."""
    generator = torch.Generator().manual_seed(seed)
    return torch.randint(0, count, (rounds, count), generator=generator)


def gap_spread(real: StatisticSet, sims: Sequence[StatisticSet], indices: Tensor, scale: Scale | None = None) -> Tensor:
    """``(rounds, len(sims))`` gaps of each simulated set on every bootstrap resample of the pairs."""
    return torch.tensor([[gap(real, sim, index, scale) for sim in sims] for index in indices])
