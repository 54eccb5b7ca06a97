"""Fit your camera: (clean, captured) pairs in, a camera profile to train with out.

    python examples/fit_camera.py PAIRS -o my-camera.safetensors     # your pairs
    python examples/fit_camera.py --demo -o out/fit-camera/demo.safetensors

PAIRS is what ``camdegrade fit`` takes: a folder holding ``clean/`` and ``captured/`` (the same relative names), or
a CSV manifest (docs/fitting.md says how to capture and lay them out). ``--demo`` has no pairs to ask for: it
generates photos (dead leaves) and captures them with camdegrade's ``phone-indoor`` virtual camera first. The fit
logs what it finds and keeps; then the profile's summary (what ``camdegrade info`` prints) and how to use it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from camdegrade import CameraDegrade, FitConfig, PairSet, fit_profile, profile_summary, simulate_pairs
from camdegrade.io import write_image
from camdegrade.synthetic import dead_leaves_images


def demo_pairs(folder: Path, count: int, size: int, seed: int) -> Path:
    """``count`` generated photos of ``size``² and their captures by a virtual camera: ``folder/pairs``."""
    for index, image in enumerate(dead_leaves_images(count, size, seed=seed)):
        write_image(image, folder / "photos" / f"{index:03d}.png")
    simulate_pairs("phone-indoor", folder / "photos", folder / "pairs", seed=seed)
    return folder / "pairs"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("pairs", nargs="?", type=Path, help="a pairs folder or CSV manifest (or --demo)")
    parser.add_argument("-o", "--output", type=Path, required=True, help="the profile to write (.safetensors)")
    parser.add_argument("--demo", action="store_true", help="fit a virtual camera's pairs instead")
    parser.add_argument("--recipe", default="fast", choices=("fast", "paper"))
    parser.add_argument("--epochs", type=int, help="at most this many epochs (default: the recipe's)")
    parser.add_argument("--align", action="store_true", help="register each pair first (sub-pixel shifts)")
    parser.add_argument("--demo-pairs", type=int, default=24, help="how many pairs --demo makes (default 24)")
    parser.add_argument("--demo-size", type=int, default=128, help="their side in pixels (default 128)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if (args.pairs is None) == (not args.demo):
        parser.error("give PAIRS or --demo (one of them)")

    if args.demo:
        source = demo_pairs(args.output.parent / "demo", args.demo_pairs, args.demo_size, args.seed)
    else:
        source = args.pairs
    pairs = PairSet.load(source, align=args.align, log=print)
    recipe = FitConfig.recipe(args.recipe, epochs=args.epochs, seed=args.seed)
    profile = fit_profile(pairs, recipe, name=args.output.stem, log=print)
    profile.save(args.output)
    print(profile_summary(args.output))

    degrade = CameraDegrade(args.output, seed=args.seed)  # a torchvision v2 transform: put it in your pipeline
    clean = pairs.images[0][0]
    degraded = degrade(clean)
    print(f"wrote {args.output}; train with CameraDegrade({str(args.output)!r}, p=0.5, seed=0) in your pipeline")
    print(f"(a clean {tuple(clean.shape)} {clean.dtype} image in, a {tuple(degraded.shape)} {degraded.dtype} one out)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
