"""Side by side for the jitter stage on City100 held-out scenes: clean | capture | built-in before the jitter step |
built-in now, a flat region at 1:1 and a textured one at 2× (nearest), and each profile's held-out PSNR of its
sample and of its deterministic output (the conditional mean) against the captures.

Usage::

    git show 8cbfe8d:src/camdegrade/profiles/city100-iphonex.safetensors > /tmp/before.safetensors
    OMP_NUM_THREADS=2 .venv/bin/python experiments/jitter_side_by_side.py /tmp/before.safetensors --png out/jitter.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
import torch.nn.functional as F
from fit_city100_default import DEFAULT_DATA, LAST_FITTED_SCENE
from PIL import Image

from camdegrade import load_profile
from camdegrade._support.pixels import as_unit
from camdegrade.fitting import discover_pairs, filter_pairs, load_pair
from camdegrade.functional.analysis.images import gradient_energy
from camdegrade.measures.metrics import psnr

SHOWN = ("060", "062", "098")
SIDE = 96


def _window(image: torch.Tensor, textured: bool) -> tuple[int, int]:
    energy = F.avg_pool2d(gradient_energy(image)[None, None], SIDE, stride=8)[0, 0]
    index = int(energy.argmax() if textured else energy.argmin())
    return 8 * (index // energy.shape[1]), 8 * (index % energy.shape[1])


def _crop(image: torch.Tensor, corner: tuple[int, int], zoom: int) -> torch.Tensor:
    top, left = corner
    cut = image[None, :, top : top + SIDE, left : left + SIDE].clamp(0, 1)
    return F.interpolate(cut, scale_factor=zoom, mode="nearest")[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("before", type=Path, help="the built-in before the jitter step (a profile file)")
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--png", type=Path, default=Path("out/jitter_city100.png"))
    args = parser.parse_args()
    profiles = {"before": load_profile(args.before), "now": load_profile("city100-iphonex")}
    pairs = [p for p in filter_pairs(discover_pairs(args.data / "pairs.csv").pairs, subset="city100_iPhoneX")]
    held = [pair for pair in pairs if pair.scene > LAST_FITTED_SCENE]
    scores = {name: {"sampled": [], "mean": []} for name in profiles}
    rows = []
    for index, pair in enumerate(held):
        clean, capture = (as_unit(image) for image in load_pair(pair))
        images = [clean, capture]
        for name, profile in profiles.items():
            sample = profile.simulate([clean], index, eight_bit=True)[0]
            mean = profile.simulate([clean], index, deterministic=True)[0]
            scores[name]["sampled"].append(psnr(sample, capture))
            scores[name]["mean"].append(psnr(mean, capture))
            images.append(sample)
        if pair.scene in SHOWN:
            flat, textured = _window(clean, False), _window(clean, True)
            rows.append(torch.cat([_crop(image, flat, 1) for image in images], -1))
            rows.append(torch.cat([_crop(image, textured, 2) for image in images], -1))
    for name, values in scores.items():
        sampled, mean = (sum(v) / len(v) for v in values.values())
        print(f"{name}: held-out PSNR sampled {sampled:.2f} dB, deterministic (conditional mean) {mean:.2f} dB")
    width = max(row.shape[-1] for row in rows)
    canvas = torch.cat([F.pad(row, (0, width - row.shape[-1]), value=1.0) for row in rows], -2)
    args.png.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray((canvas.permute(1, 2, 0) * 255).round().byte().numpy()).save(args.png)
    shown = ", ".join(SHOWN)
    print(f"wrote {args.png} (columns: clean | capture | before | now; per scene {shown}: flat 1:1, texture 2x)")


if __name__ == "__main__":
    main()
