"""Where City100's unpaired profile misses the top bands (issue 43): on the fitting sets or on new scenes only?

City100 has pairs for every scene, so what the unpaired fit cannot see can be measured here: each scene set of the
split (the clean set 001–035, the capture set 036–055, the 16 held-out scenes 056–070 and 098) with its own
captures. Printed, for the images alone: the sets' content (log2 band power of the clean images and of the captures,
set mean, relative to the capture set's) and the camera's transfer (capture over clean, per image, set mean); and per
profile: the fit's own set statistic (the clean set simulated against the capture set's captures), the paired bands
of each scene set (:mod:`camdegrade.measures.fidelity`'s five bands; centre crops of 512 and whole frames), the fit's
own normalised spectrum (:func:`~camdegrade.fitting.unpaired.steps.spectrum.log_spectrum`), and finer radial bins;
then the camera's transfer near the axes and on the diagonals. Run from the repo root::

    OMP_NUM_THREADS=1 .venv/bin/python experiments/top_bands_city100.py PROFILE [PROFILE ...] [--data DIR]
"""

from __future__ import annotations

import argparse
import itertools
import time
from pathlib import Path

import torch
from fit_city100_unpaired import CAPTURED_SCENES, CLEAN_SCENES, DEFAULT_DATA, HELD_OUT, city100
from torch import Tensor

from camdegrade import load_profile
from camdegrade._support.pixels import as_unit
from camdegrade.fitting.unpaired.steps.spectrum import SPECTRUM_SIDE, centre_crop, log_spectrum
from camdegrade.measures.fidelity import band_power, luma_spectrum, measure_fidelity

SETS = {"clean set 001-035": CLEAN_SCENES, "capture set 036-055": CAPTURED_SCENES, "held-out": HELD_OUT}
FINE_EDGES = (0.02, 0.08, 0.16, 0.25, 0.30, 0.35, 0.375, 0.40, 0.45, 0.5)
RINGS = (0.25, 0.30, 0.33, 0.35, 0.37, 0.39, 0.41, 0.45, 0.5)


def cells(values) -> str:
    return " / ".join(f"{float(value):+.2f}" for value in values)


def log_bands(images: list[Tensor]) -> Tensor:
    """``(N, 5)`` log2 band power of each image's centre crop of 512."""
    powers = [band_power(centre_crop(image, SPECTRUM_SIDE))[0] for image in images]
    return torch.stack(powers).clamp_min(1e-8).log2()


def fine_bands(images: list[Tensor]) -> Tensor:
    """``(N, len(FINE_EDGES) − 1)`` log2 power in the radial bins of :data:`FINE_EDGES` (centre crops of 512)."""
    edges = torch.tensor(FINE_EDGES)
    out = []
    for image in images:
        power, radius = luma_spectrum(centre_crop(image, SPECTRUM_SIDE))
        index = torch.bucketize(radius, edges, right=True) - 1
        out.append(torch.stack([power[0][index == band].sum() for band in range(len(edges) - 1)]))
    return torch.stack(out).clamp_min(1e-8).log2()


def sets_alone(clean: dict, real: dict) -> None:
    print("content, log2 band power, set mean, relative to the capture set's (0.02-0.08 / ... / 0.35-0.5):")
    for kind, images in (("clean", clean), ("captures", real)):
        reference = log_bands([images[scene] for scene in CAPTURED_SCENES]).mean(0)
        for name, scenes in SETS.items():
            print(f"  {kind} of the {name}: {cells(log_bands([images[s] for s in scenes]).mean(0) - reference)}")
    print("the camera's transfer (capture over clean, per image, set mean):")
    for name, scenes in SETS.items():
        ratio = log_bands([real[s] for s in scenes]) - log_bands([clean[s] for s in scenes])
        print(f"  {name}: {cells(ratio.mean(0))}")


def one_profile(path: Path, clean: dict, real: dict) -> None:
    profile = load_profile(path)
    print(f"\n{path}: {', '.join(effect.name for effect in profile.effects)}")
    sims: dict[str, Tensor] = {}
    for scenes in SETS.values():
        sims.update(zip(scenes, profile.simulate([clean[s] for s in scenes], 0, eight_bit=True), strict=True))
    own = log_bands([sims[s] for s in CLEAN_SCENES]).mean(0) - log_bands([real[s] for s in CAPTURED_SCENES]).mean(0)
    print(f"  fit's own set statistic (clean set simulated against the capture set's captures): {cells(own)}")
    for name, scenes in SETS.items():
        report = measure_fidelity([sims[s] for s in scenes], [real[s] for s in scenes], [clean[s] for s in scenes])
        print(
            f"  paired, {name}: whole frames {cells(report.bands)}, flat noise {report.noise_ratio:.2f}, "
            f"PSNR {report.psnr:.2f}"
        )
    normalised = torch.stack([log_spectrum(centre_crop(sims[s], SPECTRUM_SIDE)) for s in CLEAN_SCENES]).mean(0)
    target = torch.stack([log_spectrum(centre_crop(real[s], SPECTRUM_SIDE)) for s in CAPTURED_SCENES]).mean(0)
    print(
        f"  fit's normalised spectrum (8 bands 0.06-0.5), clean set against capture set: {cells(normalised - target)}"
    )
    print(f"  finer bins {FINE_EDGES}, paired simulation over capture:")
    for name, scenes in SETS.items():
        ratio = fine_bands([sims[s] for s in scenes]) - fine_bands([real[s] for s in scenes])
        print(f"    {name}: {cells(ratio.mean(0))}")


def directions(clean: dict, real: dict) -> None:
    """The camera's transfer (capture over clean, log2 mean power per bin) within 8° of an axis and 30–60° off."""
    print("\nthe camera's transfer by direction (capture set and held-out scenes), ring: near the axes | diagonal")
    ratios = []
    for scene in CAPTURED_SCENES + HELD_OUT:
        per_image = []
        for image in (real[scene], clean[scene]):
            power, radius = luma_spectrum(centre_crop(image, SPECTRUM_SIDE))
            fy = torch.fft.fftfreq(radius.shape[0])[:, None].abs().expand_as(radius)
            fx = torch.fft.rfftfreq(2 * (radius.shape[1] - 1))[None, :].abs().expand_as(radius)
            angle = torch.rad2deg(torch.atan2(fy, fx))
            axis, diagonal = (angle < 8) | (angle > 82), (angle > 30) & (angle < 60)
            rings = [(radius >= low) & (radius < high) for low, high in itertools.pairwise(RINGS)]
            per_image.append(torch.tensor([[power[0][r & axis].mean(), power[0][r & diagonal].mean()] for r in rings]))
        ratios.append(per_image[0].log2() - per_image[1].log2())
    for (low, high), (axis, diagonal) in zip(itertools.pairwise(RINGS), torch.stack(ratios).mean(0), strict=True):
        print(f"  {low:.2f}-{high:.2f}: {axis:+.2f} | {diagonal:+.2f}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("profiles", type=Path, nargs="*")
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    args = parser.parse_args(argv)
    if not (args.data / "pairs.csv").is_file():
        parser.error(f"no pairs.csv in {args.data}; pass --data with the real-pairs folder")
    started = time.perf_counter()
    scenes = city100(args.data)
    clean = {scene: as_unit(pair[0]) for scene, pair in scenes.items()}
    real = {scene: as_unit(pair[1]) for scene, pair in scenes.items()}
    sets_alone(clean, real)
    for path in args.profiles:
        one_profile(path, clean, real)
    directions(clean, real)
    print(f"\n{time.perf_counter() - started:.0f} s wall, {time.process_time():.0f} CPU-s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
