"""Issue 42, the flat pixels' channel test: which pixels three masks keep, and what the clean image itself leaves in
the noise statistics' high pass there (the pooled residual std of the clean image against its own 17×17 local mean,
8-bit levels: 8-bit rounding of a smooth field is about 0.29; an edge the mask let in reads as several levels).

- *channel mean*: the channel mean's gradient below 1.5 levels alone (main at cbf9d7f);
- *raw channels*: besides, each channel's raw gradient below √3 × 1.5 levels (the reverted noise42 branch, 6f260a4);
- *flat_mask*: besides the mean's test, no channel edge
  (:func:`~camdegrade.functional.analysis.images.channel_edges`: its gradient and that gradient less its 17×17 local
  mean both reach √3 × 1.5 levels), this tree's.

On the foreign cameras' walls (rectangles of random colour, ``foreign_cameras.scenes.walls``), on their scene mix
(photo crops, walls, dead leaves) and on the smooth random-colour ramps of ``tests/test_network_drop.py`` (a 4 × 4 grid
of random colours, bilinear to 96²). Run from the repo root::

    OMP_NUM_THREADS=1 .venv/bin/python experiments/channel_edges_masks.py
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from camdegrade.functional.analysis.images import (
    CHANNEL_SPREAD,
    FLAT_ERODE,
    FLAT_LEVELS,
    FLAT_SIGMA,
    flat_mask,
    gaussian_gradient_magnitude,
)
from camdegrade.functional.analysis.noise import NoiseSums

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import test_network_drop
from foreign_cameras.scenes import scenes, walls


def _eroded(mask: Tensor) -> Tensor:
    for _ in range(FLAT_ERODE):
        inner = torch.zeros_like(mask)
        inner[1:-1, 1:-1] = mask[1:-1, 1:-1] & mask[:-2, 1:-1] & mask[2:, 1:-1] & mask[1:-1, :-2] & mask[1:-1, 2:]
        mask = inner
    return mask


def channel_mean(clean: Tensor) -> Tensor:
    return _eroded(gaussian_gradient_magnitude(clean.mean(0) * 255, FLAT_SIGMA) < FLAT_LEVELS)


def raw_channels(clean: Tensor) -> Tensor:
    channels = gaussian_gradient_magnitude(clean * 255, FLAT_SIGMA).amax(0) < CHANNEL_SPREAD * FLAT_LEVELS
    return channel_mean(clean) & _eroded(channels)


def _unit(image: np.ndarray) -> Tensor:
    return torch.from_numpy(image.transpose(2, 0, 1).copy()).float() / 255


def _row(name: str, cleans: list[Tensor], masks: dict[str, Callable[[Tensor], Tensor]]) -> str:
    cells = []
    for mask_of in masks.values():
        masks_here = [mask_of(clean) for clean in cleans]
        sums = NoiseSums.zeros()
        for clean, mask in zip(cleans, masks_here, strict=True):
            sums = sums + NoiseSums.measure(clean, clean, mask)
        cells.append(f"{sum(int(m.sum()) for m in masks_here):,} / {sums.pooled_std():.3f}")
    return f"| {name} | " + " | ".join(cells) + " |"


def main() -> None:
    torch.set_num_threads(1)
    masks = {"channel mean": channel_mean, "raw channels": raw_channels, "flat_mask": flat_mask}
    rng = np.random.default_rng(3)
    sets = {
        "foreign walls, 24 of 128²": [_unit(walls(128, rng)) for _ in range(24)],
        "foreign scene mix, 24 of 128²": [_unit(image) for image in scenes(24, 128, seed=1)],
        "network-drop ramps, 6 of 96²": [clean for clean, _ in test_network_drop._pairs(noise_only=True)],
    }
    print("| clean images | " + " | ".join(f"{name}: flat pixels / clean residual" for name in masks) + " |")
    print("|---" * (len(masks) + 1) + "|")
    for name, cleans in sets.items():
        print(_row(name, cleans, masks))


if __name__ == "__main__":
    main()
