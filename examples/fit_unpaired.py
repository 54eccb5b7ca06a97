"""Fit a camera without pairs: from the camera's own photos and clean images of other scenes.

    python examples/fit_unpaired.py CAPTURES --clean CLEAN -o my-camera.safetensors
    python examples/fit_unpaired.py --demo -o out/fit-unpaired/demo.safetensors

CAPTURES is a folder of the camera's photos; CLEAN (optional, but most stages need it) a folder of clean images of
*other* scenes with similar content: no pair, no correspondence (docs/fitting.md, *Unpaired fitting*). At least 8
images a side. The profile has no network: each effect stage (blur, tone, colour, vignetting, noise, JPEG, ...) is
fitted by matching a distribution of the captures and kept only where it changes that statistic by more than the
two sets' content does. ``--demo`` generates both sets (dead leaves with grey cards) and photographs the captures'
scenes with a known camera, so the summary can be read against it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from camdegrade import VirtualCamera, fit_unpaired, profile_summary
from camdegrade.effects import Blur, Color, Noise, Tone, Vignetting
from camdegrade.synthetic import dead_leaves_images

#: The demo's camera: vignetting, lens blur, 4 levels of sensor noise, a white balance and a tone curve.
DEMO_CAMERA = (
    Vignetting(-0.4),
    Blur(1.5),
    Noise(levels=torch.full((3, 4), 4.0 / 255), linear=False),
    Color(torch.diag(torch.tensor([1.25, 1.0, 0.8]))),
    Tone(gamma=1.3),
)
DEMO_TEXT = "vignetting k1 -0.4, blur sigma 1.5 px, noise 4 levels, white balance R/G 1.25 B/G 0.8, tone gamma 1.3"


def scenes(count: int, size: int, seed: int) -> list[torch.Tensor]:
    """Generated photos with three grey cards each: texture for the spectrum, flat regions for the noise."""
    generator = torch.Generator().manual_seed(seed)
    images = []
    for image in dead_leaves_images(count, size, seed=seed):
        side = size * 5 // 16
        for _ in range(3):
            top, left = (int(value) for value in torch.randint(0, size - side, (2,), generator=generator))
            image[:, top : top + side, left : left + side] = int(torch.randint(30, 230, (), generator=generator))
        images.append(image)
    return images


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("captures", nargs="?", type=Path, help="a folder of the camera's photos (or --demo)")
    parser.add_argument("--clean", type=Path, help="a folder of clean images of other scenes")
    parser.add_argument("-o", "--output", type=Path, required=True, help="the profile to write (.safetensors)")
    parser.add_argument("--demo", action="store_true", help="fit a known camera's generated photos instead")
    parser.add_argument("--demo-images", type=int, default=16, help="images a side for --demo (default 16)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.demo == (args.captures is not None) or (args.demo and args.clean is not None):
        parser.error("give CAPTURES (and --clean CLEAN), or --demo")

    if args.demo:
        camera = VirtualCamera(DEMO_CAMERA)
        generator = torch.Generator().manual_seed(args.seed)
        captures = [camera(image, generator=generator) for image in scenes(args.demo_images, 128, args.seed + 1)]
        captured, clean = captures, scenes(args.demo_images, 128, args.seed + 2)  # other scenes: no pairs
        print(f"demo camera: {DEMO_TEXT}")
    else:
        captured, clean = args.captures, args.clean
    profile = fit_unpaired(captured, clean, seed=args.seed, name=args.output.stem, log=print)
    profile.save(args.output)
    print(profile_summary(args.output))
    print(f"wrote {args.output}; train with CameraDegrade({str(args.output)!r}, p=0.5, seed=0) in your pipeline")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
