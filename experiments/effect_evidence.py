"""Which effect stages a default fit keeps, and on what evidence: simulated cameras with known noise (issue 23).

Three virtual cameras share lens blur σ 0.7 (linear light), a 2× resolution loss and a tone curve, and store 8-bit
captures; they differ in their sensor noise: none, Poisson–Gaussian noise, and that noise with row banding. Each
gets ``--pairs`` clean images of 128² (dead-leaves texture and flat grey charts, alternately), a default fit
(``fit_profile``, fast recipe; ``--epochs`` to shorten it), and one markdown row: whether the noise stage was kept,
the captures' flat noise against the profile's without the stage (8-bit levels, validation pairs), the flat-noise
ratio without and with it, the banding decision, and the fit's own fidelity report (noise and banding ratio of the
sampled profile, critic with and without the clean source). ``--png`` writes, per camera, a flat and a textured
crop of one validation pair: clean, capture, simulation (flat at 1:1, textured at 2× nearest-neighbour). Run from
the repo root::

    OMP_NUM_THREADS=2 .venv/bin/python experiments/effect_evidence.py [--pairs 48] [--epochs 10] [--png PATH] [--log]
"""

from __future__ import annotations

import argparse
import sys
import time

import torch
import torch.nn.functional as F
from PIL import Image

from camdegrade._support.pixels import unit_to_bytes
from camdegrade.effects import Blur, Noise, Tone
from camdegrade.fitting import FitConfig, PairSet, fit_profile
from camdegrade.sim import VirtualCamera
from camdegrade.synthetic import dead_leaves_images

SIZE = 128
TONE = {"gamma": 0.8, "black": 0.02, "white": 0.95}
CAMERAS = {
    "no noise": None,
    "noise": {"a": 0.003, "b": 2e-5},
    "noise + row banding": {"a": 0.003, "b": 2e-5, "row_sigma": 0.004},
}


def chart(seed: int) -> torch.Tensor:
    """2×2 flat grey patches at least 0.28 apart, slightly tinted (flat pixels at four intensities)."""
    generator = torch.Generator().manual_seed(seed)
    grey = torch.linspace(0.08, 0.92, 4)[torch.randperm(4, generator=generator)]
    levels = (grey[None] * (0.9 + 0.2 * torch.rand(3, 1, generator=generator))).clamp(0, 1)
    return F.interpolate(levels.reshape(1, 3, 2, 2), size=(SIZE, SIZE), mode="nearest")[0]


def pairs(noise: dict | None, count: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """``count`` (clean, capture) uint8 pairs of the camera with ``noise`` (``None``: none)."""
    stages = [Blur(0.7), *([Noise(**noise)] if noise else []), Tone(**TONE)]
    camera = VirtualCamera(stages, scale=0.5)
    leaves = dead_leaves_images(count, SIZE, seed=3)
    cleans = [leaves[i] if i % 2 else unit_to_bytes(chart(i)) for i in range(count)]
    generator = torch.Generator().manual_seed(1)
    with torch.no_grad():
        return [(clean, camera(clean, generator=generator)) for clean in cleans]


def row(label: str, profile, seconds: float) -> str:
    note = profile.fitted["effects"]["noise"]
    fidelity = profile.quality["fidelity"]

    def number(value) -> str:
        return "–" if value is None else f"{value:.2f}"

    def critic(key: str) -> str:
        result = fidelity[key]
        return "–" if result is None else f"{result['accuracy']:.2f} [{result['low']:.2f}–{result['high']:.2f}]"

    banding = (
        "none fitted"
        if note.get("banding_ratio_banded") is None
        else (
            f"{number(note['banding_ratio_unbanded'])} → {number(note['banding_ratio_banded'])}, "
            f"{'kept' if note['banding_kept'] else 'dropped'}"
        )
    )
    return (
        f"| {label} | {'kept' if note['kept'] else 'dropped'} | {number(note.get('capture_noise'))} / "
        f"{number(note.get('simulation_noise'))} | {number(note.get('noise_ratio_without'))} → "
        f"{number(note.get('noise_ratio_with'))} | {banding} | {number(fidelity['noise_ratio'])} | "
        f"{number(fidelity['banding_ratio'])} | {critic('critic_paired')} | {critic('critic_image_only')} | "
        f"{seconds:.0f} s |"
    )


def crops(validation: PairSet, profile) -> Image.Image:
    """clean | capture | simulation of the first validation chart (flat, 1:1) and leaves (textured, 2×)."""
    rows = []
    for textured in (False, True):  # pair i is a chart for even i, dead leaves for odd i (see pairs)
        index = next((k for k, name in enumerate(validation.names) if int(name) % 2 == textured), None)
        if index is None:
            continue
        clean, captured = validation.unit_pairs()[index]
        sim = profile.simulate([clean], seed=0, stream="quality")[0]
        images = [unit_to_bytes(image[:, 32:96, 32:96]) for image in (clean, captured, sim)]
        if textured:
            images = [image.repeat_interleave(2, -1).repeat_interleave(2, -2) for image in images]
        rows.append(torch.cat(images, -1))
    width = max(image.shape[-1] for image in rows)
    rows = [F.pad(image, (0, width - image.shape[-1])) for image in rows]
    return Image.fromarray(torch.cat(rows, -2).permute(1, 2, 0).numpy())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=int, default=48)
    parser.add_argument("--epochs", type=int, default=FitConfig.recipe("fast").epochs)
    parser.add_argument("--png", default=None, help="write the crops of every camera, one below the other")
    parser.add_argument("--log", action="store_true", help="print each fit's log lines (stderr)")
    args = parser.parse_args()
    print(
        "| camera | noise stage | flat noise: capture / profile without (levels) | noise ratio without → with "
        "| banding: unbanded → banded | fit: noise ratio | fit: banding ratio | critic paired "
        "| critic image-only | fit |"
    )
    print("|---|---|---|---|---|---:|---:|---|---|---:|")
    pictures = []
    for label, noise in CAMERAS.items():
        pair_set = PairSet.load(pairs(noise, args.pairs))
        started = time.perf_counter()
        recipe = FitConfig.recipe("fast").replace(epochs=args.epochs)
        log = (lambda line, camera=label: print(f"  [{camera}] {line}", file=sys.stderr)) if args.log else None
        profile = fit_profile(pair_set, recipe, log=log)
        print(row(label, profile, time.perf_counter() - started), flush=True)
        _, validation = pair_set.validation_split(recipe.val_fraction, recipe.seed)
        pictures.append(crops(validation, profile))
    if args.png:
        width = max(picture.width for picture in pictures)
        canvas = Image.new("RGB", (width, sum(picture.height for picture in pictures)))
        top = 0
        for picture in pictures:
            canvas.paste(picture, (0, top))
            top += picture.height
        canvas.save(args.png)
        print(f"wrote {args.png}")


if __name__ == "__main__":
    main()
