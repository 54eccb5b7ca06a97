"""Crops of a diagnosis's held-out pairs for people: where real and simulation differ most, the flattest region at
1:1 (noise and banding show there first), and an HTML section of them side by side."""

from __future__ import annotations

import html
from collections.abc import Sequence

import torch
from torch import Tensor

from camdegrade.diagnose.report._html import image_url
from camdegrade.functional.analysis.images import flattest_window

__all__ = ["crop_grid", "example_crops", "flat_crops"]


def example_crops(
    cleans: Sequence[Tensor], reals: Sequence[Tensor], before: Sequence[Tensor], after: Sequence[Tensor], count: int = 3
) -> list[tuple[str, list[Tensor]]]:
    """Up to ``count`` crops (clean, real, sim before, sim after) from the most textured held-out images,
    taken where real and simulation before differ most (96 px at most)."""
    scored = sorted(range(len(cleans)), key=lambda i: -float((reals[i] - before[i]).abs().mean()))[:count]
    out = []
    for index in scored:
        height, width = cleans[index].shape[-2:]
        side = min(96, height, width)
        diff = (reals[index] - before[index]).abs().mean(0)
        window = torch.nn.functional.avg_pool2d(diff[None, None], side, stride=max(1, side // 4))[0, 0]
        top, left = divmod(int(window.argmax()), window.shape[-1])
        top, left = top * max(1, side // 4), left * max(1, side // 4)
        crop = (slice(top, top + side), slice(left, left + side))
        out.append(
            (
                f"held-out pair {index}",
                [image[:, crop[0], crop[1]] for image in (cleans[index], reals[index], before[index], after[index])],
            )
        )
    return out


def flat_crops(
    cleans: Sequence[Tensor], reals: Sequence[Tensor], before: Sequence[Tensor], after: Sequence[Tensor], side: int = 96
) -> list[tuple[str, list[Tensor]]]:
    """One ``side``² crop at 1:1 (real, sim before, sim after) of the held-out pair with the largest flat region,
    where the clean image is flattest: noise and banding show there first."""
    side = min(side, *(min(clean.shape[-2:]) for clean in cleans))
    windows = [flattest_window(clean, side, step=max(1, side // 4)) for clean in cleans]
    if not windows:
        return []
    best = max(range(len(windows)), key=lambda index: windows[index][1])
    (rows, cols), share = windows[best]
    crop = (slice(None), rows, cols)
    label = f"held-out pair {best}, {share:.0%} flat"
    return [(label, [image[crop] for image in (reals[best], before[best], after[best])])]


def crop_grid(title: str, crops: Sequence[tuple[str, Sequence[Tensor]]], scale: int = 2) -> str:
    """An HTML section of labelled rows of images side by side (nothing when there are none)."""
    if not crops:
        return ""
    rows = "".join(
        f"<div>{html.escape(label)}<br>"
        + "".join(f"<img src='{image_url(image, scale)}' alt=''>" for image in images)
        + "</div>"
        for label, images in crops
    )
    return f"<h2>{html.escape(title)}</h2><div class='crops'>{rows}</div>"
