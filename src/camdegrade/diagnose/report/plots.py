"""The evidence plots of a diagnosis report (matplotlib, when the optional ``report`` extra is installed), and the
same evidence as tables where it is not."""

from __future__ import annotations

import io
from typing import Any

import torch

from camdegrade.diagnose.report._html import png_url, table
from camdegrade.measures.families.frequency import BANDS, Frequency
from camdegrade.measures.families.intensity import INTENSITY_BINS
from camdegrade.measures.families.noise import NOISE_BINS, NoiseLevel
from camdegrade.measures.families.spatial import TILES

__all__ = ["evidence_plots", "fallback_tables"]


def _figure_png(figure: Any) -> str:
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=80, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(figure)
    return png_url(buffer.getvalue())


def evidence_plots(stats: dict[str, Any]) -> list[tuple[str, str]]:
    """(caption, data URL) for each evidence plot of a report's ``statistics``; empty without matplotlib or
    statistics."""
    try:
        import matplotlib

        matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt
    except ImportError:
        return []
    if not stats:
        return []
    real, before, after = stats["real"], stats["before"], stats["after"]
    plots = []
    figure, axes = plt.subplots(1, 3, figsize=(9, 3))
    vmax = max(1.0, float((real["spatial"] - before["spatial"]).abs().max()))
    for axis, (label, sim) in zip(axes, (("before", before), ("after", after), ("", None)), strict=True):
        if sim is None:
            axis.axis("off")
            continue
        diff = (real["spatial"] - sim["spatial"]).reshape(3, TILES, TILES).mean(0)
        shown = axis.imshow(diff.numpy(), cmap="coolwarm", vmin=-vmax, vmax=vmax)
        axis.set_title(f"real − sim {label} (levels)")
        axis.set_xticks([])
        axis.set_yticks([])
    figure.colorbar(shown, ax=axes[2], fraction=0.8)
    plots.append(("Spatial map: mean difference per tile (vignetting, tone, colour)", _figure_png(figure)))

    figure, axes = plt.subplots(1, 3, figsize=(10, 3))
    centres = (torch.arange(INTENSITY_BINS) + 0.5) / INTENSITY_BINS
    for name, sim, style in (("sim before", before, "--"), ("sim after", after, ":")):
        axes[0].plot(centres, (real["intensity"] - sim["intensity"]).reshape(3, -1).T.numpy(), style)
        axes[0].plot([], [], "k" + style, label=name)
    axes[0].axhline(0, color="k", lw=0.5)
    axes[0].set_title("tone residual real − sim (levels)")
    axes[0].set_xlabel("clean value")
    axes[0].legend(fontsize=7)
    centres = (torch.arange(NOISE_BINS) + 0.5) / NOISE_BINS
    for name, values, style in (("real", real, "-"), ("sim before", before, "--"), ("sim after", after, ":")):
        axes[1].plot(centres, torch.nanmean(values["noise"].reshape(3, -1), 0).numpy(), "k" + style, label=name)
    axes[1].set_title("noise-level function (std, levels)")
    axes[1].set_xlabel("clean value")
    axes[1].legend(fontsize=7)
    frequencies = (torch.arange(1, BANDS) + 0.5) / BANDS * 0.5
    for name, values, style in (("real", real, "-"), ("sim before", before, "--"), ("sim after", after, ":")):
        axes[2].plot(frequencies, values["frequency"].numpy(), "k" + style, label=name)
    axes[2].set_title("transfer vs clean (rel. to lowest band)")
    axes[2].set_xlabel("cycles / pixel")
    axes[2].legend(fontsize=7)
    figure.tight_layout()
    plots.append(("Intensity, noise and frequency signatures", _figure_png(figure)))
    return plots


def fallback_tables(stats: dict[str, Any]) -> str:
    """The evidence of the plots as tables, where matplotlib is not installed."""
    if not stats:
        return ""
    real, before, after = stats["real"], stats["before"], stats["after"]
    rows = []
    for name in (NoiseLevel.name, Frequency.name):
        for k in range(real[name].numel()):
            rows.append(
                (
                    name,
                    k,
                    f"{float(real[name][k]):.3f}",
                    f"{float(before[name][k]):.3f}",
                    f"{float(after[name][k]):.3f}",
                )
            )
    return "<h2>Signatures (tables: install the 'report' extra for plots)</h2>" + table(
        rows, ("statistic", "bin/band", "real", "sim before", "sim after")
    )
