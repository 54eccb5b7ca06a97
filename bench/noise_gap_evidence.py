"""Why a row of the PSNR-gap bench (``bench_noise_gap.py``) falls short: the noise of each row's simulation of the
held-out clean images against the camera's real noise there, measured the same way on the residual
``noisy − clean``.

- on the clean images' flat pixels (:func:`~camdegrade.functional.analysis.images.flat_mask`) where the noisy image does
  not clip, the residual less its 17×17 local mean (as :class:`~camdegrade.functional.analysis.noise.NoiseSums`
  takes it): the std per channel and intensity bin, the correlation with the neighbour 1 to 4 pixels away (mean of
  horizontal and vertical and of the channels), the mean correlation between channels, and the kurtosis (3 for
  Gaussian noise; per image, then the mean, so that images of different noise levels do not make a heavy-tailed
  mixture);
- ``textured / flat``: the residual's std on the unclipped pixels that are not flat over its std on the flat ones
  (a camera's ISP sharpens and compresses at edges; additive noise is the same everywhere);
- ``8x8``: the residual's luma gradient across the 8×8 grid's block boundaries over its mean gradient
  (:func:`~camdegrade.measures.families.blocks.block_phase_energy`; 1: no grid; a JPEG quantises the noise block by
  block);
- ``clipped``: the share of pixels at 0 or 255 in some channel (where noise is clipped, its mean shifts);
- ``colour``: the share of the residual's luma power in each of the five radial bands of
  :data:`~camdegrade.measures.fidelity.BAND_EDGES` (cycles per pixel) on the flattest 128² window of each image, as
  a log2 ratio to the real noise's share (0: the same spectral shape whatever the level; negative: too little of the
  noise at those frequencies).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from PIL import Image, ImageDraw
from torch import Tensor

from camdegrade.functional.analysis.images import box_mean, flat_mask, flattest_window, gradient_energy
from camdegrade.functional.analysis.noise import HIGH_PASS, NoiseSums
from camdegrade.measures.families.blocks import block_phase_energy
from camdegrade.measures.fidelity import band_power

#: Side of the flattest window the bands are measured on (SIDD's smallest held-out image is 241²).
WINDOW = 128
#: Lags (pixels) of the spatial correlation.
LAGS = (1, 2, 3, 4)
#: The panel's tiles: a flat crop at 1:1 and a textured crop of half the side at 2× (nearest).
TILE = 128


def noise_structure(noisies: Sequence[Tensor], cleans: Sequence[Tensor]) -> dict[str, Any]:
    """The residual statistics of ``noisies`` around ``cleans`` (float ``(3, H, W)`` in [0, 1], in pairs)."""
    sums, lags = NoiseSums.zeros(), torch.zeros(len(LAGS), 3, dtype=torch.float64)
    flat_square = textured_square = torch.zeros(2, dtype=torch.float64)
    shares, blocks, kurtosis, clipped, pixels = [], [], [], 0, 0
    for noisy, clean in zip(noisies, cleans, strict=True):
        residual, flat = noisy - clean, flat_mask(clean)
        sums = sums + NoiseSums.measure(residual, clean, flat, clipping=noisy)
        unclipped = ((noisy > 0) & (noisy < 1)).all(0)
        clipped += int((~unclipped).sum())
        detail = (residual - box_mean(residual, HIGH_PASS)) * 255.0
        lags += _lag_sums(detail, flat & unclipped)
        flat_square = flat_square + _square_sums(residual, flat & unclipped)
        textured_square = textured_square + _square_sums(residual, ~flat & unclipped)
        kurtosis.append(_kurtosis(detail[:, flat & unclipped]))
        power = band_power(residual[(slice(None), *flattest_window(clean, WINDOW)[0])] + 0.5)[0]
        shares.append(power / power.sum())
        energy, mean = block_phase_energy(residual + 0.5)
        blocks.append(float((energy[7] + energy[15]) / (mean[7] + mean[15])))
        pixels += noisy.shape[-1] * noisy.shape[-2]
    channels = sums.channel_correlation()
    products, first, second = lags.unbind(-1)
    return {
        "flat_pixels": sums.pixels,
        "std_levels": _listed(sums.std()),
        "flat_std_levels": round(_std(flat_square), 3),
        "correlation_lags_1_to_4": _listed(products / (first * second).clamp_min(1e-30).sqrt()),
        "channel_correlation": round(float(channels[~torch.eye(3, dtype=torch.bool)].mean()), 3),
        "kurtosis": round(sum(kurtosis) / len(kurtosis), 2),
        "textured_over_flat": round(_std(textured_square) / _std(flat_square), 3),
        "block_boundary_ratio": round(sum(blocks) / len(blocks), 3),
        "clipped_share": round(clipped / pixels, 4),
        "band_share": _listed(torch.stack(shares).mean(0)),
    }


def _lag_sums(detail: Tensor, mask: Tensor) -> Tensor:
    """``(len(LAGS), 3)``: ``Σ r₀ r_d``, ``Σ r₀²``, ``Σ r_d²`` over the pairs of flat pixels ``d`` apart (horizontal
    and vertical pairs together, all channels)."""
    out = []
    for lag in LAGS:
        pairs = [
            (detail[..., :, :-lag], detail[..., :, lag:], mask[:, :-lag] & mask[:, lag:]),
            (detail[..., :-lag, :], detail[..., lag:, :], mask[:-lag, :] & mask[lag:, :]),
        ]
        total = torch.zeros(3, dtype=torch.float64)
        for here, there, both in pairs:
            a, b = here[:, both].double(), there[:, both].double()
            total += torch.stack([(a * b).sum(), (a * a).sum(), (b * b).sum()])
        out.append(total)
    return torch.stack(out)


def _square_sums(residual: Tensor, mask: Tensor) -> Tensor:
    """``(Σ r², count)`` of the residual (levels) on ``mask``, the image's channel means removed (a brightness
    offset is not noise)."""
    values = residual[:, mask].double() * 255.0
    centred = values - values.mean(-1, keepdim=True)
    return torch.stack([centred.pow(2).sum(), torch.tensor(float(centred.numel()), dtype=torch.float64)])


def _std(sums: Tensor) -> float:
    return float(sums[0] / sums[1].clamp_min(1)) ** 0.5


def _kurtosis(values: Tensor) -> float:
    values = values.double().flatten()
    variance = values.pow(2).mean()
    return float(values.pow(4).mean() / variance.pow(2).clamp_min(1e-30))


def _listed(values: Tensor) -> list[float | None]:
    return [round(float(v), 4) if torch.isfinite(v) else None for v in values.flatten()]


def band_log2_ratio(row: dict[str, Any], real: dict[str, Any]) -> list[float]:
    """``log2(row / real)`` of the residual's band shares."""
    return [round(float(torch.log2(torch.tensor(r / q))), 2) for r, q in zip(row["band_share"], real["band_share"])]


def format_evidence(subset: str, structures: dict[str, dict[str, Any]]) -> str:
    """One line per row: flat std, textured/flat, lag correlations, channel correlation, kurtosis, band ratios;
    then the std per intensity bin (mean over channels) of each row over the real one's."""
    real = structures["real"]
    header = (
        f"{subset:<20} {'row':<17} {'σ flat':>6} {'tex/flat':>8} {'corr lag 1 2 3 4':>23} {'chroma':>6} "
        f"{'kurt':>5} {'8x8':>5} {'clipped':>7} {'colour: log2 share / real, low→high':>36}"
    )
    lines = [header]
    for name, row in structures.items():
        correlation = " ".join("  n/m" if v is None else f"{v:5.2f}" for v in row["correlation_lags_1_to_4"])
        bands = " ".join(f"{v:6.2f}" for v in band_log2_ratio(row, real))
        lines.append(
            f"{'':<20} {name:<17} {row['flat_std_levels']:>6.2f} {row['textured_over_flat']:>8.2f} {correlation:>23} "
            f"{row['channel_correlation']:>6.2f} {row['kurtosis']:>5.1f} {row['block_boundary_ratio']:>5.2f} "
            f"{row['clipped_share']:>7.2%} {bands:>36}"
        )
    lines.append(f"{'':<20} σ per intensity bin (8 bins of the clean value, mean over channels), row / real:")
    real_bins = _channel_mean(real["std_levels"])
    lines.append(f"{'':<20} {'real (levels)':<17} " + " ".join(_cell(v) for v in real_bins))
    for name, row in structures.items():
        if name != "real":
            ratios = [
                None if r is None or q is None else r / q for r, q in zip(_channel_mean(row["std_levels"]), real_bins)
            ]
            lines.append(f"{'':<20} {name:<17} " + " ".join(_cell(v) for v in ratios))
    return "\n".join(lines)


def _channel_mean(std: list[float | None]) -> list[float | None]:
    bins = len(std) // 3
    out = []
    for index in range(bins):
        values = [std[channel * bins + index] for channel in range(3)]
        out.append(None if any(v is None for v in values) else sum(values) / 3)
    return out


def _cell(value: float | None) -> str:
    return "  n/m" if value is None else f"{value:5.2f}"


def crops(noisies: dict[str, Tensor], clean: Tensor) -> list[tuple[str, list[Tensor]]]:
    """A flat crop (1:1) and a textured crop (2×, nearest) of ``clean`` and of each row's noisy image of it, uint8."""
    flat, _ = flattest_window(clean, TILE)
    half = TILE // 2
    energy = F.avg_pool2d(gradient_energy(clean)[None, None], half, stride=8)[0, 0]
    top, left = (8 * v for v in divmod(int(energy.argmax()), energy.shape[1]))
    textured = (slice(top, top + half), slice(left, left + half))
    images = {"clean": clean, **noisies}
    tiles = []
    for kind, window, scale in (("flat 1:1", flat, 1), ("textured 2x", textured, 2)):
        cut = [images[name][(slice(None), *window)] for name in images]
        cut = [F.interpolate(c[None], scale_factor=scale, mode="nearest")[0] if scale > 1 else c for c in cut]
        tiles.append((kind, [(c.clamp(0, 1) * 255).round().to(torch.uint8) for c in cut]))
    return tiles


def write_panel(panels: dict[str, list[tuple[str, list[Tensor]]]], columns: Sequence[str], path: Path) -> None:
    """Rows of tiles (per subset: flat, textured), one column per image, with labels."""
    label_width, label_height, gap = 150, 16, 4
    rows = [(f"{subset} {kind}", tiles) for subset, panel in panels.items() for kind, tiles in panel]
    canvas = Image.new(
        "RGB", (label_width + len(columns) * (TILE + gap), label_height + len(rows) * (TILE + gap)), "white"
    )
    draw = ImageDraw.Draw(canvas)
    for index, name in enumerate(columns):
        draw.text((label_width + index * (TILE + gap), 2), name, fill="black")
    for row, (label, tiles) in enumerate(rows):
        y = label_height + row * (TILE + gap)
        draw.text((4, y + TILE // 2 - 6), label.replace("_real_noise", "").replace("_samples", ""), fill="black")
        for index, tile in enumerate(tiles):
            canvas.paste(Image.fromarray(tile.permute(1, 2, 0).numpy()), (label_width + index * (TILE + gap), y))
    path.parent.mkdir(parents=True, exist_ok=True)
    canvas.save(path)
