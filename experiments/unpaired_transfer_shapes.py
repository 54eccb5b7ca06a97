"""Which transfer-function shape the iPhone X of City100 has, seen by the unpaired fit's spectrum statistic (issue 27).

The unpaired fit matches the mean log power spectrum of the captures (8 radial bands from 0.058 to 0.5
cycles/pixel, each image's contrast taken out: :func:`camdegrade.fitting.unpaired.steps.spectrum.mean_spectrum`) by
simulating a clean set of other scenes. Here, on its split (clean 001–035, captures 036–055), each family of
shapes is searched on a grid and its best mismatch (mean squared log2 power difference) printed: a Gaussian PSF with
an unsharp mask of radius 0.5–4 px (the fit's family has radius 1), a PSF whose MTF is ``exp(−(f/f₀)^p)`` (p 1, 1.5:
heavier tails than a Gaussian's p = 2), and a sensor of 0.35–0.5 of the pixels upscaled (with blur and sharpening).
Every chain ends in JPEG at quality 98 (what the fit estimated for these captures from their block-edge energy until
issue 44; they hold no quantisation lattice, and the fit now gives them no codec stage). Then the residual of the best
Gaussian-plus-unsharp chain per band, between the fitting sets and on the 16 held-out *pairs* (no content
difference there): the same shape on both is the camera's, which a radial detail response fitted on the sets
carries over. Run from the repo root (about 3 minutes on 2 cores)::

    OMP_NUM_THREADS=2 .venv/bin/python experiments/unpaired_transfer_shapes.py [--data DIR]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import torch
from torch import Tensor

sys.path.insert(0, str(Path(__file__).resolve().parent))

from fit_city100_unpaired import CAPTURED_SCENES, CLEAN_SCENES, DEFAULT_DATA, HELD_OUT, city100

from camdegrade import CameraProfile
from camdegrade._support.pixels import as_unit
from camdegrade.effects import JPEG, Blur, Effect, FrequencyResponse, Resolution, Sharpen
from camdegrade.effects.base import evenly_spaced
from camdegrade.fitting.unpaired.steps.spectrum import SPECTRUM_SIDE, band_centres, centre_crop, mean_spectrum

BLURS = (1.0, 1.125, 1.25, 1.375, 1.5)
AMOUNTS = (0.0, 0.25, 0.5, 0.75, 1.0)


def _simulate(chain: list[Effect], images: list[Tensor]) -> list[Tensor]:
    profile, generator = CameraProfile(None, [*chain, JPEG(98)]), torch.Generator().manual_seed(0)
    with torch.no_grad():
        return [
            profile(image[None], profile.make_params((1, *image.shape), generator))[0].mul(255).round().div(255)
            for image in images
        ]


def _mtf(p: float, gain_at_02: float) -> FrequencyResponse:
    """A response of MTF ``exp(−(f/f₀)^p)`` with ``gain_at_02`` at 0.2 cycles/pixel, at every knot (21 per axis; no
    band left at 1: the reference bands that take out each image's contrast are filtered too, as a lens would)."""
    knots = torch.linspace(0.0, 0.5, 21, dtype=torch.float64)
    radius = (knots[:, None] ** 2 + knots[None, :] ** 2).sqrt()
    scale = 0.2 / (-math.log(gain_at_02)) ** (1 / p)
    return FrequencyResponse(torch.exp(-((radius / scale) ** p)).float())


def families() -> dict[str, list[tuple[str, list[Effect]]]]:
    out: dict[str, list[tuple[str, list[Effect]]]] = {}
    for radius in (0.5, 1.0, 2.0, 3.0, 4.0):
        out[f"Gaussian + unsharp radius {radius:g}"] = [
            (f"σ {sigma}, amount {amount}", [Blur(sigma), *([Sharpen(radius, amount)] if amount else [])])
            for sigma in BLURS
            for amount in AMOUNTS
        ]
    for p in (1.0, 1.5, 2.0):
        out[f"MTF exp(-(f/f0)^{p:g})"] = [
            (f"gain {gain} at 0.2", [_mtf(p, gain), *([Sharpen(1.0, amount)] if amount else [])])
            for gain in (0.1, 0.2, 0.3, 0.4, 0.5, 0.6)
            for amount in (0.0, 0.5)
        ]
    out["upscale from a smaller sensor"] = [
        (
            f"scale {scale}, σ {sigma}, amount {amount}",
            [*([Blur(sigma)] if sigma else []), *([Sharpen(1.0, amount)] if amount else []), Resolution(scale)],
        )
        for scale in (0.35, 0.4, 0.45, 0.5)
        for sigma in (0.0, 0.6, 1.0)
        for amount in (0.0, 1.0, 2.0)
    ]
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    args = parser.parse_args(argv)
    if not (args.data / "pairs.csv").is_file():
        parser.error(f"no pairs.csv in {args.data}; pass --data with the real-pairs folder")
    scenes = city100(args.data)
    captures = [as_unit(scenes[scene][1]) for scene in CAPTURED_SCENES]
    crops = evenly_spaced([centre_crop(as_unit(scenes[scene][0]), SPECTRUM_SIDE) for scene in CLEAN_SCENES], 24)
    real = mean_spectrum(captures)
    fit_family = "Gaussian + unsharp radius 1"
    fit_best: tuple[Tensor, list[Effect]] | None = None  # the fit's own family: its residual and its chain
    print("| family | best mismatch | at |\n|---|---|---|")
    for family, candidates in families().items():
        scored = [(mean_spectrum(_simulate(chain, crops)) - real, label, chain) for label, chain in candidates]
        residual, label, chain = min(scored, key=lambda item: float(item[0].pow(2).mean()))
        print(f"| {family} | {float(residual.pow(2).mean()):.3f} | {label} |", flush=True)
        if family == fit_family:
            fit_best = (residual, chain)
    assert fit_best is not None
    sets, chain = fit_best
    held_clean = [centre_crop(as_unit(scenes[scene][0]), SPECTRUM_SIDE) for scene in HELD_OUT]
    held_real = mean_spectrum([as_unit(scenes[scene][1]) for scene in HELD_OUT])
    pairs = mean_spectrum(_simulate(chain, held_clean)) - held_real
    centres = " / ".join(f"{value:.3f}" for value in band_centres()[1:].tolist())
    print(f"\nresidual of the fit's family (radius 1) per band, log2 power sim − real (bands centred at {centres}):")
    print("fitting sets:    " + " / ".join(f"{value:+.2f}" for value in sets.tolist()))
    print("held-out pairs:  " + " / ".join(f"{value:+.2f}" for value in pairs.tolist()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
