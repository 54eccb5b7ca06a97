"""Generated clean images, seeded: the dead-leaves model (distillation trains on them; the CPU inference plan probes
a network with them).

Occluding discs whose radii follow ``p(r) ∝ r⁻³`` (scale invariance, as in natural images) give sharp edges at
every scale, flat regions and a natural power spectrum; with random colours (mostly muted, some dark, some
saturated), a smooth illumination and a touch of fine texture, the regimes a camera network meets in photographs
(flat, edge, texture, dark, bright, saturated) all occur.

References:
    G. Matheron, "Modèle séquentiel de partition aléatoire", technical report, CMM, 1968; A. B. Lee, D. Mumford,
    J. Huang, "Occlusion models for natural images: a statistical study of a scale-invariant dead leaves model",
    International Journal of Computer Vision 41(1), 2001.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from PIL import Image, ImageDraw
from torch import Tensor

from camdegrade._support.pixels import bytes_to_unit, unit_to_bytes
from camdegrade._support.seeds import derived_generator

__all__ = ["COVERAGE", "MIN_RADIUS", "dead_leaves_image", "dead_leaves_images"]

#: Discs smaller than this (pixels) are not drawn: near a pixel they would only add aliasing.
MIN_RADIUS = 2.0
#: How many times the discs cover the canvas on average: at 4, less than 2 % of it shows the background.
COVERAGE = 4.0


def dead_leaves_image(size: int, generator: torch.Generator) -> Tensor:
    """One ``(3, size, size)`` uint8 dead-leaves image drawn from ``generator``.

    Discs with radii from :data:`MIN_RADIUS` to ``size / 3`` (density ``∝ r⁻³``) are laid one over the other,
    as many as cover the canvas :data:`COVERAGE` times on average; then a smooth illumination (a gentle gradient
    across the frame) and fine texture of about one 8-bit level.
    """
    if isinstance(size, bool) or not isinstance(size, int) or size < 4:
        raise ValueError(f"size must be an integer >= 4, got size={size!r}")
    low, high = MIN_RADIUS, max(size / 3.0, MIN_RADIUS * 2)
    # E[r²] of p(r) ∝ r⁻³ on [low, high] is ln(high / low) / ((low⁻² − high⁻²) / 2).
    mean_area = math.pi * math.log(high / low) / ((low**-2 - high**-2) / 2)
    discs = math.ceil(COVERAGE * size * size / mean_area)
    uniform = torch.rand(discs + 1, 6, generator=generator)
    # Inverse CDF of p(r) ∝ r⁻³ on [low, high]: 1/r² is uniform between 1/high² and 1/low².
    radii = (1.0 / (low**-2 + uniform[1:, 0] * (high**-2 - low**-2))).sqrt().tolist()
    centres = (uniform[1:, 1:3] * size).tolist()
    colours = unit_to_bytes(_colours(uniform[:, 3:6])).tolist()
    canvas = Image.new("RGB", (size, size), tuple(colours[0]))
    draw = ImageDraw.Draw(canvas)
    for (y, x), radius, colour in zip(centres, radii, colours[1:], strict=True):
        draw.ellipse((x - radius, y - radius, x + radius, y + radius), fill=tuple(colour))
    image = bytes_to_unit(torch.from_numpy(np.asarray(canvas).copy()).permute(2, 0, 1))
    return unit_to_bytes(_lit(image, generator), overwrite=True)


def _lit(image: Tensor, generator: torch.Generator) -> Tensor:
    """``image`` under a smooth illumination (up to ±15 % across the frame) with fine texture (std 0.004)."""
    size = image.shape[-1]
    ramp = torch.linspace(-0.5, 0.5, size)
    slope = (torch.rand(2, generator=generator) - 0.5) * 0.3
    light = 1.0 + slope[0] * ramp[:, None] + slope[1] * ramp[None, :]
    texture = torch.randn(1, size, size, generator=generator) * 0.004
    return (image * light + texture).clamp(0.0, 1.0)


def dead_leaves_images(count: int, size: int = 256, *, seed: int = 0) -> list[Tensor]:
    """``count`` dead-leaves images (:func:`dead_leaves_image`), image ``i`` from the seed stream
    ``(seed, "dead-leaves", i)``: the same ``(seed, i)`` gives the same bytes, whatever ``count`` is."""
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise ValueError(f"count must be a positive integer, got count={count!r}")
    return [dead_leaves_image(size, derived_generator(seed, "dead-leaves", index)) for index in range(count)]


def _colours(uniform: Tensor) -> Tensor:
    """Colours with natural variety: mostly muted (a grey level tinted), some dark, some saturated."""
    grey = uniform[:, :1] ** 1.5  # more dark than bright, as photographs hold
    tint = (uniform - 0.5) * torch.where(uniform[:, 1:2] > 0.85, 1.6, 0.5)  # 15 % saturated
    return (grey + tint).clamp(0.0, 1.0)
