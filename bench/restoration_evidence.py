"""Why a row of the restoration-transfer bench (``bench_restoration_transfer.py``) transfers or not: where in the
spectrum each restorer's output differs from the clean image, and crops to look at.

Per band of :data:`~camdegrade.measures.fidelity.BAND_EDGES` (radial, cycles/pixel), summed over the aligned tiles
of the held-out images (:mod:`aligned_scoring`, so that misregistration is not read as missing detail):

- ``log2 output/clean``: the luma power of the output over the clean image's (0: the clean image's detail;
  below: detail not restored; above: over-sharpened or texture of its own);
- ``error gain dB``: ``10·log10`` of the capture's error power (capture − clean) in the band over the output's
  (above 0: the restorer took error out of that band; below: it put error in);
- ``coherence``: how much of what the output holds in the band is the clean image's detail (:func:`coherence`).

The same measures of each row's training input against the clean image, on the training scenes, show what the
restorer learns from: detail the input holds coherently is detail it learns to bring back.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from itertools import pairwise

import torch
import torch.nn.functional as F
from aligned_scoring import Aligned
from torch import Tensor

from camdegrade.functional.analysis.images import gradient_energy
from camdegrade.measures.fidelity import BAND_EDGES, band_power

#: Side of the textured crops of the panel (shown at 2×, nearest).
CROP = 64
BANDS = [f"{low:g}–{high:g}" for low, high in pairwise(BAND_EDGES)]


def band_sums(aligned: Aligned) -> dict[str, list[float]]:
    """Luma power per band summed over the tiles: of the aligned output, of the clean tiles, of their difference
    and of their sum (the two give the cross power: ``P(x + c) − P(x − c) = 4·Re(X·C*)``)."""
    tiles, references = aligned.tiles, aligned.references
    return {
        "output": band_power(tiles).sum(0).tolist(),
        "clean": band_power(references).sum(0).tolist(),
        "error": band_power(tiles - references).sum(0).tolist(),
        "sum": band_power(tiles + references).sum(0).tolist(),
    }


def added(sums: Sequence[Mapping[str, Sequence[float]]]) -> dict[str, list[float]]:
    """The band sums of several images (or seeds) added up."""
    return {key: [sum(values) for values in zip(*(s[key] for s in sums), strict=True)] for key in sums[0]}


def coherence(sums: Mapping[str, Sequence[float]]) -> list[float]:
    """Per band, the correlation of the output's spectrum with the clean image's, ``Re Σ X·C* / √(Σ|X|² Σ|C|²)``
    over the tiles: 1 where the output holds the clean image's detail (at any gain), 0 where what it holds there
    is unrelated to it (noise, aliasing, codec texture, detail misplaced by more than the band's wavelength)."""
    return [
        round((total - error) / (4 * math.sqrt(output * clean)), 3)
        for total, error, output, clean in zip(sums["sum"], sums["error"], sums["output"], sums["clean"], strict=True)
    ]


def band_profile(sums: Mapping[str, Sequence[float]], capture: Mapping[str, Sequence[float]]) -> dict[str, list]:
    """``log2 output/clean``, ``error gain dB`` (module docstring) and :func:`coherence` per band of one row's
    summed bands against the capture's."""
    return {
        "log2_output_over_clean": [
            round(math.log2(o / c), 3) for o, c in zip(sums["output"], sums["clean"], strict=True)
        ],
        "error_gain_db": [
            round(10 * math.log10(x / e), 3) for e, x in zip(sums["error"], capture["error"], strict=True)
        ],
        "coherence": coherence(sums),
        "log2_output_over_capture": [
            round(math.log2(o / x), 3) for o, x in zip(sums["output"], capture["output"], strict=True)
        ],
    }


def textured_window(clean: Tensor, side: int = CROP) -> tuple[int, int]:
    """Top-left corner of the ``side``² window of ``clean`` with the most gradient energy (on an 8-pixel grid)."""
    energy = F.avg_pool2d(gradient_energy(clean)[None, None], side, stride=8)[0, 0]
    top, left = divmod(int(energy.argmax()), energy.shape[1])
    return 8 * top, 8 * left


def crop_2x(image: Tensor, window: tuple[int, int], side: int = CROP) -> Tensor:
    """The uint8 ``side``² crop of ``image`` at ``window``, enlarged 2× (nearest neighbour)."""
    top, left = window
    cut = image[None, :, top : top + side, left : left + side].clamp(0, 1)
    return (F.interpolate(cut, scale_factor=2, mode="nearest")[0] * 255).round().to(torch.uint8)


def format_bands(profiles: Mapping[str, Mapping[str, list]], keys: Sequence[str]) -> str:
    """A markdown table: per row, the band measures ``keys`` of :func:`band_profile`."""
    heads = {
        "log2_output_over_clean": "log2 power over the clean image's",
        "log2_output_over_capture": "log2 power over the capture's",
        "error_gain_db": "error gain dB",
        "coherence": "coherence with the clean image",
    }
    lines = ["| row | " + " | ".join(heads[key] for key in keys) + " |", "|---|" + "---|" * len(keys)]
    for name, profile in profiles.items():
        cells = [" / ".join(f"{v:+.2f}" if key != "coherence" else f"{v:.2f}" for v in profile[key]) for key in keys]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
