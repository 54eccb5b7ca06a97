"""Issue 43, what the step width leaves: is City100's iPhone X a sensor of fewer pixels, read without a prefilter and
upscaled? Hand-made chains on the 16 held-out clean images, not fits: a Gaussian blur (σ ``pre``), every ``factor``-th
pixel (no prefilter, so fine detail aliases), a bicubic upscale back, a Gaussian blur (σ ``post``), an unsharp mask
(radius ``radius``, ``amount``), then the tone stage of an unpaired profile (``--profile``). Printed beside the
captures and the profile itself: the median step width (:func:`~camdegrade.functional.analysis.edges.step_widths`),
the median thin-line width (:func:`~camdegrade.functional.analysis.edges.line_widths`), band log2 power,
flat-noise ratio and PSNR; and a side-by-side PNG (clean | capture | profile | each chain; the most textured window
of 062, 098 and 060 at 2×).
Run from the repo root::

    OMP_NUM_THREADS=1 .venv/bin/python experiments/aliasing_sensor_city100.py --profile PROFILE [--png PATH]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
import torch.nn.functional as F
from fidelity_report import best_window, labelled_grid, save_png
from fit_city100_unpaired import DEFAULT_DATA, HELD_OUT, TILE, city100
from PIL import Image
from torch import Tensor

from camdegrade import CameraProfile, load_profile
from camdegrade._support.pixels import as_unit, unit_to_bytes
from camdegrade.functional.analysis.edges import line_widths, step_widths
from camdegrade.functional.analysis.images import gradient_energy
from camdegrade.functional.optics.blur import blur_image
from camdegrade.measures.fidelity import measure_fidelity

#: label → (pre σ, factor, post σ, unsharp amount, unsharp radius)
CHAINS = {
    "1/3, pre 1.0, post 1.0": (1.0, 3, 1.0, 0.0, 1.5),
    "+ unsharp 1.5 px x1": (1.0, 3, 1.0, 1.0, 1.5),
    "+ unsharp 2 px x1.5": (1.0, 3, 1.0, 1.5, 2.0),
    "1/2, pre 1.0, post 1.2": (1.0, 2, 1.2, 0.0, 1.5),
}
SHOWN = ("062", "098", "060")


def sensor(image: Tensor, pre: float, factor: int, post: float, amount: float, radius: float) -> Tensor:
    """``image`` through the hand-made chain of :data:`CHAINS` (before the tone stage)."""
    height, width = image.shape[-2:]
    small = blur_image(image, pre)[:, ::factor, ::factor]
    upscaled = blur_image(F.interpolate(small[None], size=(height, width), mode="bicubic")[0], post)
    return (upscaled + amount * (upscaled - blur_image(upscaled, radius))).clamp(0, 1)


def _stored(images: list[Tensor]) -> list[Tensor]:
    return [image.mul(255).round().div(255) for image in images]


def widths(images: list[Tensor]) -> str:
    steps = torch.cat([step_widths(image) for image in images])
    lines = torch.cat([line_widths(image) for image in images])
    return f"{float(steps.median()):.2f} | {float(lines.median()):.2f}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--profile", type=Path, required=True, help="an unpaired profile of the split (its tone)")
    parser.add_argument("--png", type=Path, default=Path("out/results/aliasing_sensor_city100.png"))
    args = parser.parse_args()
    scenes = city100(args.data)
    cleans = [as_unit(scenes[scene][0]) for scene in HELD_OUT]
    reals = [as_unit(scenes[scene][1]) for scene in HELD_OUT]
    profile = load_profile(args.profile)
    tone = CameraProfile(None, [effect for effect in profile.effects if effect.name == "tone"])
    sims = {"profile": _stored(profile.simulate(cleans, 0))}
    for label, chain in CHAINS.items():
        sims[label] = _stored(tone.simulate([sensor(clean, *chain) for clean in cleans], 0))
    print("| simulation | step px | line px | band log2 | flat-noise ratio | PSNR dB |\n|---|---|---|---|---|---|")
    print(f"| captures | {widths(reals)} | | | |")
    for label, images in sims.items():
        report = measure_fidelity(images, reals, cleans).to_dict(digits=3)
        bands = " / ".join(f"{value:+.2f}" for value in report["bands"])
        print(f"| {label} | {widths(images)} | {bands} | {report['noise_ratio']:.2f} | {report['psnr']:.2f} |")
    rows = []
    for scene in SHOWN:
        index = HELD_OUT.index(scene)
        top, left = best_window(gradient_energy(cleans[index]), TILE // 2)
        images = [cleans[index], reals[index], *(sim[index] for sim in sims.values())]
        crops = [unit_to_bytes(image[:, top : top + TILE // 2, left : left + TILE // 2]) for image in images]
        tiles = [Image.fromarray(crop.permute(1, 2, 0).numpy()).resize((TILE, TILE), Image.NEAREST) for crop in crops]
        rows.append((f"{scene} texture 2x", tiles))
    save_png(labelled_grid(["clean", "capture", *sims], rows, TILE, header=28), args.png)
    print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
