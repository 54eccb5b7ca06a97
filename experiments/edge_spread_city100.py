"""Issue 43: a statistic of the camera's blur that texture (aliasing, noise, codec) cannot fake, on City100 iPhone X.

The median 10–90 % width of strong isolated step edges (:func:`camdegrade.functional.analysis.edges.step_widths`)
and the median half-maximum width of thin isolated lines (a ridge with flat ground on both sides,
:func:`~camdegrade.functional.analysis.edges.line_widths`), of the captures and of simulations of the clean images:
the clean images blurred by Gaussians (σ, through :func:`~camdegrade.functional.optics.blur.blur_image`), the built-in
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
from fit_city100_unpaired import CAPTURED_SCENES, CLEAN_SCENES, DEFAULT_DATA, HELD_OUT, city100
from torch import Tensor

from camdegrade import load_profile
from camdegrade._support.pixels import as_unit
from camdegrade.functional.analysis.edges import line_widths, step_widths
from camdegrade.functional.optics.blur import blur_image

SIGMAS = (1.0, 1.25, 1.5, 1.75)


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
