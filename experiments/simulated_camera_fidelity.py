"""Issue 23's simulated cameras: does a default fit look like its own camera on pairs it never saw?

Two virtual cameras, each with ``--pairs`` training pairs and ``--held-out`` new ones (other images, other draws):

- ``soft``: lens blur σ 0.7 (linear light), a 2× resolution loss, a tone curve and NO sensor noise (8-bit only);
- ``dark``: Poisson–Gaussian sensor noise, then exposure × 0.25 (a colour matrix of 0.25 in linear light) and a tone
  curve.

Clean images of 128²: dead-leaves texture and flat tinted grey charts, alternately. Each camera gets a default fit
(``fit_profile``, fast recipe) and, on the held-out pairs: the sampled profile's paired PSNR beside the least-squares
linear baseline's (:mod:`camdegrade.fitting.network.baseline`, fitted on the same training pairs: a 7×7 colour filter
plus an offset, of which a 12-number colour map and a Gaussian blur are special cases), the stages kept, the grid ratio,
band powers and flat-noise ratio (:func:`camdegrade.measures.fidelity.measure_fidelity`), a critic with and
without the clean source for the profile and for the baseline (8 critics: 4 seeds, each trained on half the
held-out pairs and scored on the other half, and back; :func:`camdegrade.measures.critic.repeated_critic_test`;
mean, std, 95 % interval) and, with ``--diagnose``, what
:func:`camdegrade.diagnose` accepts on those pairs. ``--png``: clean, capture, profile, baseline (flat crop at 1:1,
textured crop at 2×, nearest). Run from the repo root::

    OMP_NUM_THREADS=2 .venv/bin/python experiments/simulated_camera_fidelity.py [--pairs 240] [--held-out 64] \
        [--cameras soft dark] [--diagnose] [--png out/simulated_cameras.png] [--upsample smooth] [--curves none] \
        [--texture none] [--sensor-scale 0.5]
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict

import torch
from effect_evidence import SIZE, chart
from PIL import Image

from camdegrade._support.pixels import as_unit, unit_to_bytes
from camdegrade._support.recipes import CURVES, TEXTURES, UPSAMPLINGS
from camdegrade.diagnose import diagnose
from camdegrade.effects import Blur, Color, Noise, Tone
from camdegrade.fitting import FitConfig, fit_profile
from camdegrade.fitting.network.baseline import apply_linear_baseline, fit_linear_baseline
from camdegrade.measures.critic import repeated_critic_test
from camdegrade.measures.fidelity import measure_fidelity
from camdegrade.measures.metrics import psnr
from camdegrade.sim import VirtualCamera
from camdegrade.synthetic import dead_leaves_images

NOISE = {"a": 0.012, "b": 8e-5}


def camera(name: str) -> VirtualCamera:
    if name == "soft":
        return VirtualCamera([Blur(0.7), Tone(gamma=0.8, black=0.02, white=0.95)], scale=0.5, name=name)
    if name == "dark":
        # the sensor's noise, then the ISP darkens the frame four times (what a short exposure leaves after gain)
        return VirtualCamera([Noise(**NOISE), Color(torch.eye(3) * 0.25), Tone(gamma=0.7, black=0.01)], name=name)
    raise ValueError(f"camera must be 'soft' or 'dark', got {name!r}")


def pairs(name: str, count: int, seed: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """``count`` uint8 (clean, capture) pairs; ``seed`` picks the images and the camera's draws."""
    leaves = dead_leaves_images(count, SIZE, seed=seed)
    cleans = [leaves[i] if i % 2 else unit_to_bytes(chart(seed * 100_003 + i)) for i in range(count)]
    generator = torch.Generator().manual_seed(seed)
    device = camera(name)
    with torch.no_grad():
        return [(clean, device(clean, generator=generator)) for clean in cleans]


#: Critic seeds per row: each trains one critic on the even held-out pairs and one on the odd ones (8 critics): one
#: critic of the soft camera reads anything from 0.60 to 0.99 (experiments/critic_seeds.py).
CRITIC_SEEDS = 4


def critic_pair(cleans: list, reals: list, sims: list) -> dict[str, list[float]]:
    """Critic accuracy (mean of :data:`CRITIC_SEEDS` × 2 critics), the critics' std and the bootstrap interval over
    pairs, image-only and paired: each critic trained on the even pairs and scored on the odd ones, or back."""
    names = [f"{index:04d}" for index in range(len(cleans))]  # in sorted order the pairs alternate even, odd
    out = {}
    for label, image_only in (("image_only", True), ("paired", False)):
        result = repeated_critic_test((cleans, reals, sims), names, CRITIC_SEEDS, image_only=image_only)
        out[label] = [round(result.accuracy, 3), round(result.std, 3), round(result.low, 3), round(result.high, 3)]
    return out


def evaluate(name: str, args: argparse.Namespace) -> tuple[dict, list[torch.Tensor]]:
    train, held = pairs(name, args.pairs, seed=3), pairs(name, args.held_out, seed=11)
    started = time.perf_counter()
    lines: list[str] = []
    recipe = FitConfig.recipe(
        "fast", upsample=args.upsample, curves=args.curves, texture=args.texture, sensor_scale=args.sensor_scale
    )
    profile = fit_profile(train, recipe, log=lines.append)
    fit_seconds = time.perf_counter() - started
    if args.save:
        profile.save(f"{args.save}-{name}.safetensors")
    baseline = fit_linear_baseline(train, seed=0)
    cleans = [as_unit(clean) for clean, _ in held]
    reals = [as_unit(captured) for _, captured in held]
    sims = [(s.clamp(0, 1) * 255).round() / 255 for s in profile.simulate(cleans, seed=0, stream="heldout")]
    with torch.no_grad():
        base = [(apply_linear_baseline(*baseline, c[None])[0].clamp(0, 1) * 255).round() / 255 for c in cleans]
    means = profile.simulate(cleans, seed=0, deterministic=True)
    fidelity = measure_fidelity(sims, reals, cleans)
    row = {
        "camera": name,
        "fit_seconds": round(fit_seconds, 1),
        "network": profile.fitted.get("network"),
        "stages": [type(effect).__name__ for effect in profile.effects],
        "texture": profile.fitted.get("texture"),
        "denoise": profile.fitted.get("denoise"),
        "response": profile.fitted.get("response"),
        "resolution": profile.fitted.get("resolution"),
        "best_epoch": profile.fitted["best_epoch"],
        "warnings": profile.fitted.get("warnings", []),
        "psnr_network": round(sum(psnr(m, r) for m, r in zip(means, reals)) / len(means), 2),
        "psnr_profile": round(sum(psnr(s, r) for s, r in zip(sims, reals)) / len(sims), 2),
        "psnr_baseline": round(sum(psnr(b, r) for b, r in zip(base, reals)) / len(base), 2),
        "fidelity": asdict(fidelity),
        "critic_profile": critic_pair(cleans, reals, sims),
        "critic_baseline": critic_pair(cleans, reals, base),
    }
    if args.diagnose:
        print(json.dumps(row), flush=True)  # before the diagnosis, which takes minutes
        report = diagnose(profile, held, seed=0)
        row["diagnose_accepted"] = list(report.accepted)
        row["diagnose_verdict"] = report.verdict
    return row, [cleans[0], reals[0], sims[0], base[0], cleans[1], reals[1], sims[1], base[1]]


def panel(rows: list[list[torch.Tensor]], path: str) -> None:
    """Per camera: a flat crop (chart, 1:1) and a textured one (leaves, 2× nearest) of clean, capture, profile and
    baseline."""
    tiles = []
    for images in rows:
        flat = torch.cat([image[:, 32:96, 32:96] for image in images[:4]], 2)
        textured = torch.cat([_twice(image[:, 40:72, 40:72]) for image in images[4:]], 2)
        tiles += [flat, textured]
    grid = torch.cat(tiles, 1)
    Image.fromarray(unit_to_bytes(grid).permute(1, 2, 0).numpy()).resize(
        (grid.shape[2] * 2, grid.shape[1] * 2), Image.NEAREST
    ).save(path)


def _twice(image: torch.Tensor) -> torch.Tensor:
    return image.repeat_interleave(2, 1).repeat_interleave(2, 2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=240)
    parser.add_argument("--held-out", type=int, default=64)
    parser.add_argument("--cameras", nargs="+", default=["soft", "dark"], choices=["soft", "dark"])
    parser.add_argument("--diagnose", action="store_true")
    parser.add_argument("--upsample", default=None, choices=UPSAMPLINGS, help="default: the fast recipe's")
    parser.add_argument("--curves", default=None, choices=CURVES, help="default: the fast recipe's")
    parser.add_argument("--texture", default=None, choices=TEXTURES, help="default: the fast recipe's")
    parser.add_argument("--sensor-scale", type=float, default=None, help="the recipe's sensor_scale (soft: 0.5)")
    parser.add_argument("--png", default=None)
    parser.add_argument("--json", default=None)
    parser.add_argument("--save", default=None, help="write each fitted profile to SAVE-CAMERA.safetensors")
    args = parser.parse_args()
    rows, crops = [], []
    for name in args.cameras:
        row, images = evaluate(name, args)
        rows.append(row)
        crops.append(images)
        print(json.dumps(row), flush=True)
    if args.png:
        panel(crops, args.png)
    if args.json:
        with open(args.json, "w") as handle:
            json.dump(rows, handle, indent=1)


if __name__ == "__main__":
    main()
