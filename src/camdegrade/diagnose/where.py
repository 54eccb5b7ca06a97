"""Where the gap lies: one human-readable finding per statistic family, with its score and null band."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor

from camdegrade.diagnose.stats import BANDS, FAMILIES, INTENSITY_BINS, NOISE_BINS, SHIFT_TILES, TILES, StatisticSet
from camdegrade.effects import EFFECTS
from camdegrade.functional.noise_stats import LAGS, MIN_LINES, MIN_PIXELS

_CHANNELS = ("R", "G", "B")


def suspects(axis: str) -> str:
    """The registered effects whose signature ``axis`` carries (:attr:`Effect.explains`; a hint, the ranking
    decides), or ``"the network"`` when no effect explains it."""
    names = [name for name, effect in EFFECTS.items() if axis in effect.explains]
    return ", ".join(names) or "the network"


def _tile_radius(tiles: int) -> Tensor:
    centers = (torch.arange(tiles) + 0.5) / tiles - 0.5
    y, x = torch.meshgrid(centers, centers, indexing="ij")
    return torch.sqrt(x**2 + y**2) / (0.5 * 2**0.5)


def _spatial(diff: Tensor) -> str:
    maps = diff.reshape(3, TILES, TILES)
    luma = maps.mean(0)
    r2 = _tile_radius(TILES).pow(2)
    design = torch.stack([torch.ones_like(r2), r2], -1).reshape(-1, 2)
    coef = torch.linalg.lstsq(design, luma.reshape(-1, 1)).solution[:, 0]
    mean = maps.mean((1, 2))
    return f"real − sim: {coef[1]:+.1f} levels from centre to corners (radial), mean offset " + ", ".join(
        f"{c} {m:+.1f}" for c, m in zip(_CHANNELS, mean.tolist(), strict=True)
    )


def _intensity(diff: Tensor) -> str:
    table = diff.reshape(3, INTENSITY_BINS)
    luma = torch.nanmean(table, 0)
    valid = torch.isfinite(luma)
    if not bool(valid.any()):
        return "no populated intensity bins"
    worst = int(torch.where(valid, luma.abs(), torch.tensor(-1.0)).argmax())
    centre = (worst + 0.5) / INTENSITY_BINS
    return f"real − sim tone residual up to {luma[worst]:+.1f} levels at clean value {centre:.2f}"


def _noise(real: Tensor, sim: Tensor, pixels: int) -> str:
    r = torch.nanmean(real.reshape(3, NOISE_BINS), 1)
    if not bool(torch.isfinite(r).any()):
        return f"noise not measurable: {pixels:,} pixels where the clean image is flat (a bin needs {MIN_PIXELS:,})"
    s = torch.nanmean(sim.reshape(3, NOISE_BINS), 1)
    return (
        f"noise std on {pixels:,} flat pixels (levels): real "
        + ", ".join(f"{c} {a:.2f}" for c, a in zip(_CHANNELS, r.tolist(), strict=True))
        + " vs sim "
        + ", ".join(f"{c} {b:.2f}" for c, b in zip(_CHANNELS, s.tolist(), strict=True))
    )


def _noise_correlation(real: Tensor, sim: Tensor, pixels: int) -> str:
    if not bool(torch.isfinite(real).any()):
        return f"noise correlation not measurable: {pixels:,} flat pixels (needs {MIN_PIXELS:,})"

    def lag1(values: Tensor) -> tuple[float, float]:
        lags = values[: 2 * len(LAGS) * 3].reshape(2, len(LAGS), 3)
        return float(lags[0, 0].mean()), float(lags[1, 0].mean())

    def chroma(values: Tensor) -> float:
        return float(values[2 * len(LAGS) * 3 :].mean())

    (rh, rv), (sh, sv) = lag1(real), lag1(sim)
    return (
        f"noise correlation with the next pixel: real h {rh:.2f} v {rv:.2f} vs sim h {sh:.2f} v {sv:.2f}; "
        f"between channels real {chroma(real):.2f} vs sim {chroma(sim):.2f} ({pixels:,} flat pixels)"
    )


def _banding(real: Tensor, sim: Tensor, lines: tuple[int, int]) -> str:
    rows, columns = lines
    if not bool(torch.isfinite(real).any()):
        return f"banding not measurable: {rows} rows, {columns} columns with enough flat pixels (needs {MIN_LINES})"
    r, s = real.reshape(2, 3).nanmean(1), sim.reshape(2, 3).nanmean(1)
    return (
        f"std of row means real {r[0]:.2f} vs sim {s[0]:.2f} levels, of column means real {r[1]:.2f} vs sim "
        f"{s[1]:.2f} ({rows:,} rows, {columns:,} columns on flat pixels)"
    )


def _frequency(real: Tensor, sim: Tensor) -> str:
    band = BANDS - 3  # well above the lowest band, below the noisy top one
    frequency = (band + 1 + 0.5) / BANDS * 0.5
    ratio = real[band] / sim[band] if float(sim[band]) != 0 else float("nan")
    kind = "softer (blur)" if ratio < 1 else "sharper"
    return f"real/sim transfer at {frequency:.2f} cycles/px: {ratio:.2f} ({kind} than simulated)"


def _blocks(real: Tensor, sim: Tensor) -> str:
    edge = (real[7] + real[15]) / 2
    simulated = (sim[7] + sim[15]) / 2
    return f"gradient energy on 8×8 block edges: real {edge:.2f}× the mean vs sim {simulated:.2f}×"


def _color(diff: Tensor) -> str:
    matrix = diff.reshape(3, 3)
    i, j = divmod(int(matrix.abs().argmax()), 3)
    gains = matrix.diagonal()
    return (
        f"real − sim colour matrix: largest {matrix[i, j]:+.3f} ({_CHANNELS[i]}←{_CHANNELS[j]}); diagonal "
        + ", ".join(f"{g:+.3f}" for g in gains.tolist())
    )


def _alignment(diff: Tensor) -> str:
    shifts = diff.reshape(SHIFT_TILES * SHIFT_TILES, 3, 2)
    mean = torch.nanmean(shifts[:, 1], 0)
    centers = (torch.arange(SHIFT_TILES) + 0.5) / SHIFT_TILES - 0.5
    y, x = torch.meshgrid(centers, centers, indexing="ij")
    direction = torch.stack([x.flatten(), y.flatten()], -1)
    green = shifts[:, 1] - mean
    radial = torch.nanmean((green * direction).sum(-1) / direction.pow(2).sum(-1).clamp_min(1e-6))
    chroma = []
    for channel in (0, 2):
        relative = shifts[:, channel] - shifts[:, 1]
        chroma.append(float(torch.nanmean((relative * direction).sum(-1) / direction.pow(2).sum(-1))))
    return (
        f"real − sim shift (green) dx {mean[0]:+.2f}, dy {mean[1]:+.2f} px; radial scale {radial:+.2f} px per "
        f"half-width; red/blue vs green radial {chroma[0]:+.2f}/{chroma[1]:+.2f}"
    )


#: axis → how its real and simulated values read to a person (the real set passed for its pixel counts).
_DESCRIBE: dict[str, Callable[[Tensor, Tensor, StatisticSet], str]] = {
    "spatial": lambda r, s, _: _spatial(r - s),
    "intensity": lambda r, s, _: _intensity(r - s),
    "noise": lambda r, s, real: _noise(r, s, real.flat_pixels()),
    "noise_correlation": lambda r, s, real: _noise_correlation(r, s, real.flat_pixels()),
    "banding": lambda r, s, real: _banding(r, s, real.lines()),
    "frequency": lambda r, s, _: _frequency(r, s),
    "blocks": lambda r, s, _: _blocks(r, s),
    "color": lambda r, s, _: _color(r - s),
    "alignment": lambda r, s, _: _alignment(r - s),
}


def findings(
    real: StatisticSet, sim: StatisticSet, scores: dict[str, float], nulls: dict[str, float]
) -> list[dict[str, Any]]:
    """One entry per family, largest score first: ``axis``, ``finding``, ``score``, ``null`` and ``significant``."""
    real_values, sim_values = real.values(), sim.values()
    out = []
    for name in FAMILIES:
        r, s = real_values[name], sim_values[name]
        text = _DESCRIBE[name](r, s, real)
        score = scores[name]
        null = nulls.get(name, 0.0)
        out.append(
            {
                "axis": name,
                "finding": f"{text} [suspects: {suspects(name)}]",
                "score": round(score, 4),
                "null": round(null, 4),
                "significant": score > max(3 * null, 1.0),
            }
        )
    return sorted(out, key=lambda entry: -entry["score"])
