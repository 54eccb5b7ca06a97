"""A foreign camera's 5-bit buffer before its tone table against camdegrade's simulation with a fitted quantization
stage, side by side on a smooth gradient (1:1) and on a textured photo crop (2× nearest neighbour).

Each base (``webcam``: 2× PIL bicubic zoom after the table; ``phone``: nothing after it) is its default fit (the
foreign bench's, ``/tmp/foreign/fits`` or ``--fits``) with the ``quantization`` stage fitted in its chain
(:meth:`Quantization.fit_in_chain`) on the withheld-effect scenario's diagnosis pairs. Columns: the clean image,
the foreign camera's capture, the profile without the stage, the profile with it. Run from the repo root::

    OMP_NUM_THREADS=1 PYTHONPATH=src .venv/bin/python experiments/quantization_side_by_side.py \\
        --fits /tmp/foreign/fits --out docs/quantization_gradient.png
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch
from PIL import Image

REPOSITORY = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPOSITORY / "bench"))
sys.path.insert(0, str(REPOSITORY / "tests"))

from foreign_bench import DIAGNOSIS_SEED, OTHER_PHOTOS, make_pairs  # noqa: E402

from camdegrade import load_profile  # noqa: E402
from camdegrade._support.pixels import as_unit  # noqa: E402
from camdegrade.effects import Quantization  # noqa: E402
from camdegrade.fitting.in_chain import fit_stage_in_chain  # noqa: E402
from foreign_cameras import SCENARIOS, scenes  # noqa: E402


def gradient(height: int = 96, width: int = 256) -> np.ndarray:
    """A smooth ramp from black to white across, warm to cool down (uint8 ``(H, W, 3)``)."""
    ramp = np.linspace(0.0, 1.0, width)[None, :, None]
    tint = np.linspace(-0.08, 0.08, height)[:, None, None] * np.array([1.0, 0.0, -1.0])
    return np.round(np.clip(ramp + tint, 0, 1) * 255).astype(np.uint8)


def as_array(image: torch.Tensor) -> np.ndarray:
    return np.round(as_unit(image).clamp(0, 1).permute(1, 2, 0).numpy() * 255).astype(np.uint8)


def row(base: str, fits: Path, clean: np.ndarray, zoom: int) -> tuple[np.ndarray, Quantization]:
    """Clean | capture | profile | profile + fitted quantization, each ``zoom``× nearest neighbour."""
    profile = load_profile(fits / f"{base}-64x128.safetensors")
    scenario = SCENARIOS[base]["quantization"].camera()
    pairs = make_pairs(scenario, 24, 128, DIAGNOSIS_SEED, OTHER_PHOTOS)
    stage = fit_stage_in_chain(profile, Quantization, [c for c, _ in pairs], [x for _, x in pairs])
    tensor = torch.from_numpy(clean.transpose(2, 0, 1).copy())
    panels = [
        clean,
        scenario(clean, seed=(7, 0)),
        as_array(profile.simulate([tensor], 7)[0]),
        as_array(profile.with_effects(stage).simulate([tensor], 7)[0]),
    ]
    gap = np.full((clean.shape[0] * zoom, 4, 3), 255, np.uint8)
    zoomed = [panel.repeat(zoom, 0).repeat(zoom, 1) for panel in panels]
    return np.concatenate([part for panel in zoomed for part in (panel, gap)][:-1], axis=1), stage


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fits", type=Path, default=Path("/tmp/foreign/fits"))
    parser.add_argument("--out", type=Path, default=Path("quantization_gradient.png"))
    args = parser.parse_args()
    texture = scenes(1, 64, seed=11)[0]
    rows = []
    for base in ("webcam", "phone"):
        smooth, stage = row(base, args.fits, gradient(), 1)
        textured, _ = row(base, args.fits, texture, 2)
        print(f"{base}: fitted {stage.levels} levels ({stage.bits:.2f} bits) on a grid of {float(stage.scale):.3g}")
        width = max(smooth.shape[1], textured.shape[1])
        for panel in (smooth, textured):
            padded = np.full((panel.shape[0], width, 3), 255, np.uint8)
            padded[:, : panel.shape[1]] = panel
            rows += [padded, np.full((6, width, 3), 255, np.uint8)]
    Image.fromarray(np.concatenate(rows[:-1], axis=0)).save(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
