"""Render docs/effects_gallery.png: every camera effect, and two virtual-camera presets, on one photo.

Usage::

    python experiments/effects_gallery.py [--out docs/effects_gallery.png] [--tile 144]

Strengths are exaggerated where an effect is subtle at thumbnail size (chromatic aberration, distortion).
Everything is seeded, so the image is reproducible byte for byte.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import skimage.data
import torch
import torch.nn.functional as F
from PIL import Image, ImageDraw

from camdegrade import effects as fx
from camdegrade.io import atomic_path
from camdegrade.sim import VirtualCamera

COLUMNS = 5
LABEL_HEIGHT = 16


def source_photo(tile: int) -> torch.Tensor:
    """The astronaut photo, centre-cropped around the face and resized to ``tile`` pixels."""
    image = torch.from_numpy(skimage.data.astronaut()).permute(2, 0, 1).float() / 255
    crop = image[:, 0:400, 60:460]
    return F.interpolate(crop[None], size=(tile, tile), mode="bilinear", antialias=True)[0]


def panels() -> list[tuple[str, fx.Effect | VirtualCamera | None]]:
    return [
        ("clean", None),
        ("blur sigma=1.2, motion 3px", fx.Blur(1.2, motion_length=3.0, motion_angle=30.0)),
        ("noise a=0.01 b=1e-4 +rows", fx.Noise(0.01, 1e-4, 0.01)),
        ("vignetting k1=-0.6", fx.Vignetting(-0.6)),
        ("jpeg quality 12", fx.JPEG(12)),
        ("chrom. aberration ±2%", fx.ChromaticAberration(0.02, -0.02)),
        ("misalignment 4px, 3°", fx.Misalignment(4.0, -2.0, 3.0)),
        ("color (warm cast)", fx.Color(torch.tensor([[1.25, 0.05, 0.0], [0.0, 1.0, 0.0], [0.0, 0.05, 0.7]]))),
        ("tone (low dyn. range)", fx.Tone(1.2, -0.12, 0.8)),
        ("sharpen sigma=1.5 amount=2", fx.Sharpen(1.5, 2.0, 0.01)),
        ("distortion k1=0.25", fx.Distortion(0.25)),
        ("preset lowcost-robot", VirtualCamera.from_preset("lowcost-robot")),
        ("preset phone-indoor", VirtualCamera.from_preset("phone-indoor")),
    ]


def render(tile: int, seed: int = 0) -> Image.Image:
    clean = source_photo(tile)[None]
    items = panels()
    rows = -(-len(items) // COLUMNS)
    canvas = Image.new("RGB", (COLUMNS * tile, rows * (tile + LABEL_HEIGHT)), "white")
    draw = ImageDraw.Draw(canvas)
    for index, (label, stage) in enumerate(items):
        generator = torch.Generator().manual_seed(seed + index)
        if stage is None:
            out = clean
        elif isinstance(stage, VirtualCamera):
            out = stage(clean, generator=generator)
        else:
            out = stage(clean, stage.make_params(clean.shape, generator))
        pixels = out[0].clamp(0, 1).mul(255).round().to(torch.uint8).permute(1, 2, 0).numpy()
        left, top = (index % COLUMNS) * tile, (index // COLUMNS) * (tile + LABEL_HEIGHT)
        canvas.paste(Image.fromarray(np.ascontiguousarray(pixels)), (left, top + LABEL_HEIGHT))
        draw.text((left + 3, top + 2), label, fill="black")
    return canvas


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--out", type=Path, default=Path(__file__).resolve().parents[1] / "docs" / "effects_gallery.png"
    )
    parser.add_argument("--tile", type=int, default=144, help="tile size in pixels")
    args = parser.parse_args(argv)
    image = render(args.tile)
    with atomic_path(args.out) as temporary:
        image.save(temporary, format="PNG", optimize=True)
    print(f"wrote {args.out} ({args.out.stat().st_size // 1024} KiB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
