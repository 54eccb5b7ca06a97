"""Issue 43: a statistic of the camera's blur that texture (aliasing, noise, codec) cannot fake, on City100 iPhone X.

The median 10–90 % width of strong isolated step edges (:func:`camdegrade.functional.analysis.edges.step_widths`)
and, for comparison, the median half-maximum width of thin isolated lines (a ridge with flat ground on both sides,
this script's own :func:`line_widths`), of the captures and of simulations of the clean images: the clean images
blurred by Gaussians (σ, through :func:`~camdegrade.functional.optics.blur.blur_image`), the built-in
``city100-iphonex`` (the paired fit) and the profiles given. On the 16 held-out pairs (056–070, 098) and on the
unpaired split's fitting sets (captures 036–055, clean 001–035), with the captures' own median under 3 and 6 levels
of added noise. Run from the repo root::

    OMP_NUM_THREADS=1 .venv/bin/python experiments/edge_spread_city100.py [--profiles A.safetensors B.safetensors]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch
import torch.nn.functional as F
from fit_city100_unpaired import CAPTURED_SCENES, CLEAN_SCENES, DEFAULT_DATA, HELD_OUT, city100
from torch import Tensor

from camdegrade import load_profile
from camdegrade._support.pixels import as_unit
from camdegrade.functional.analysis.edges import step_widths
from camdegrade.functional.analysis.images import luma
from camdegrade.functional.optics.blur import blur_image

SIGMAS = (1.0, 1.25, 1.5, 1.75)
LINE_HALF, LINE_BASE, LINE_HEIGHT = 7, (4, 7), 30.0


def _line_profiles(gray: Tensor) -> Tensor:
    """Profiles across near-vertical thin lines of ``gray`` (levels): a local extremum of the second difference
    along x, ground 4–7 px either side flat and level within a fifth of the line's height, at least
    :data:`LINE_HEIGHT` levels high; each 0 at the ground, 1 at the peak."""
    second = torch.zeros_like(gray)
    second[:, 1:-1] = gray[:, 2:] + gray[:, :-2] - 2 * gray[:, 1:-1]
    size = second.abs()
    candidate = (size == F.max_pool1d(size[:, None, :], 5, 1, 2)[:, 0, :]) & (size > 0)
    along = torch.zeros_like(gray)
    along[1:-1] = (gray[2:] - gray[:-2]) / 2
    candidate[:2], candidate[-2:] = False, False
    candidate[:, :LINE_HALF], candidate[:, -LINE_HALF:] = False, False
    rows, cols = candidate.nonzero(as_tuple=True)
    profile = gray[rows[:, None], cols[:, None] + torch.arange(-LINE_HALF, LINE_HALF + 1)[None, :]]
    left = profile[:, LINE_HALF - LINE_BASE[1] : LINE_HALF - LINE_BASE[0] + 1]
    right = profile[:, LINE_HALF + LINE_BASE[0] : LINE_HALF + LINE_BASE[1] + 1]
    ground = (left.mean(1) + right.mean(1)) / 2
    height = profile[:, LINE_HALF] - ground
    spread = torch.maximum(left.amax(1) - left.amin(1), right.amax(1) - right.amin(1))
    kept = (height.abs() >= LINE_HEIGHT) & ((left.mean(1) - right.mean(1)).abs() <= 0.2 * height.abs())
    kept &= (spread <= 0.2 * height.abs()) & (along[rows, cols].abs() <= 0.2 * height.abs())
    return (profile[kept] - ground[kept, None]) / height[kept, None]


def line_widths(image: Tensor) -> Tensor:
    """Half-maximum widths (px) of the thin isolated near-axis lines of ``image`` (``(3, H, W)`` in [0, 1])."""
    gray = luma(image.double()) * 255.0
    out = []
    for oriented in (gray, gray.T.contiguous()):
        profile = _line_profiles(oriented)
        index = torch.arange(profile.shape[1] - 1)
        rises = (profile[:, :-1] < 0.5) & (profile[:, 1:] >= 0.5) & (index < LINE_HALF)
        falls = (profile[:, :-1] >= 0.5) & (profile[:, 1:] < 0.5) & (index >= LINE_HALF)
        start = torch.where(rises, index, torch.full_like(index, -1)).amax(1)
        end = torch.where(falls, index, torch.full_like(index, 10**6)).amin(1)
        found = (start >= 0) & (end < profile.shape[1] - 1)
        start, end, profile = start[found], end[found], profile[found]
        a0, a1 = profile.gather(1, start[:, None])[:, 0], profile.gather(1, start[:, None] + 1)[:, 0]
        b0, b1 = profile.gather(1, end[:, None])[:, 0], profile.gather(1, end[:, None] + 1)[:, 0]
        out.append((end + (b0 - 0.5) / (b0 - b1).clamp_min(1e-9)) - (start + (0.5 - a0) / (a1 - a0).clamp_min(1e-9)))
    return torch.cat(out)


def _stored(images: list[Tensor]) -> list[Tensor]:
    return [image.mul(255).round().div(255) for image in images]


def row(label: str, images: list[Tensor]) -> str:
    steps = torch.cat([step_widths(image) for image in images])
    lines = torch.cat([line_widths(image) for image in images])
    return f"| {label} | {float(steps.median()):.2f} ({len(steps)}) | {float(lines.median()):.2f} ({len(lines)}) |"


def table(title: str, cleans: list[Tensor], reals: list[Tensor], profiles: dict[str, object]) -> None:
    print(f"\n{title}\n\n| images | step 10–90 % width px (steps) | line half-maximum width px (lines) |")
    print("|---|---|---|")
    print(row("captures", reals), flush=True)
    generator = torch.Generator().manual_seed(0)
    for levels in (3, 6):
        noisy = [(image + torch.randn(image.shape, generator=generator) * levels / 255).clamp(0, 1) for image in reals]
        print(row(f"captures + {levels} levels of noise", _stored(noisy)), flush=True)
    print(row("clean images", cleans), flush=True)
    for sigma in SIGMAS:
        print(row(f"clean, Gaussian σ {sigma}", _stored([blur_image(image, sigma) for image in cleans])), flush=True)
    for label, profile in profiles.items():
        print(row(label, _stored(profile.simulate(cleans, 0))), flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--profiles", type=Path, nargs="*", default=[], help="unpaired profiles to simulate too")
    args = parser.parse_args()
    started = time.perf_counter()
    scenes = {scene: (as_unit(clean), as_unit(real)) for scene, (clean, real) in city100(args.data).items()}
    profiles = {"built-in city100-iphonex": load_profile("city100-iphonex")}
    profiles |= {path.name: load_profile(path) for path in args.profiles}
    held = [scenes[scene] for scene in HELD_OUT]
    table("held-out pairs 056–070, 098", [c for c, _ in held], [r for _, r in held], profiles)
    fitting = [scenes[scene][0] for scene in CLEAN_SCENES], [scenes[scene][1] for scene in CAPTURED_SCENES]
    table("fitting sets: clean 001–035, captures 036–055", *fitting, profiles)
    print(f"\n{time.perf_counter() - started:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
