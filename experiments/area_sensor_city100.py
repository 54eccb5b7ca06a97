"""Issue 43: the unpaired fit's area-sensor step on City100's unpaired split, on the 16 held-out pairs.

Reads an unpaired profile of the split (``fit_city100_unpaired.py --out``) and builds a second from it: the sensor
its area-sensor step found (``fitted["effects"]["area_sensor"]``: on the whole sets where kept, else on the first
half; an optical blur, a sensor read by area, an unsharp mask after its upscale) in place of its blur and
sharpening, nothing else refitted: what the step refused, to look at. Prints each one's band log2 power, flat-noise
ratio, PSNR and repeated image-only critic (``two_sample_city100.rows``), the median step and thin-line widths of the
captures and of each simulation, and writes the evidence page (clean | capture | profile | with the sensor |
built-in; flat at 1:1, texture at 2x). Run
from the repo root::

    OMP_NUM_THREADS=1 .venv/bin/python experiments/area_sensor_city100.py --profile P.safetensors [--png PATH]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from fit_city100_unpaired import DEFAULT_DATA, HELD_OUT
from torch import Tensor
from two_sample_city100 import city100, evidence_page, format_table, rows, stored

from camdegrade import CameraProfile, load_profile
from camdegrade.effects import Blur, Resolution, Sharpen
from camdegrade.fitting.unpaired.bench import AREA_ORDER
from camdegrade.functional.analysis.edges import line_widths, step_widths


def with_sensor(profile: CameraProfile) -> CameraProfile:
    """``profile`` with the sensor its area-sensor step found in place of its blur and sharpening."""
    record = profile.fitted["effects"]["area_sensor"]
    chosen = record.get("chosen") or record["found_on_halves"][0]  # not kept: the sensor found on the first half
    stages = {effect.name: effect for effect in profile.effects if effect.name not in (Blur.name, Sharpen.name)}
    if chosen["pre"] > 0:
        stages[Blur.name] = Blur(chosen["pre"])
    stages[Resolution.name] = Resolution(chosen["scale"], chosen["kernel"], "area")
    if chosen["amount"] > 0:
        stages[Sharpen.name] = Sharpen(chosen["sharpen_sigma"], chosen["amount"])
    return CameraProfile(None, [stages[name] for name in AREA_ORDER if name in stages])


def widths(images: list[Tensor]) -> str:
    steps = torch.cat([step_widths(image) for image in images])
    lines = torch.cat([line_widths(image) for image in images])
    return f"steps {float(steps.median()):.2f} px, lines {float(lines.median()):.2f} px"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--profile", type=Path, required=True, help="an unpaired profile of the split")
    parser.add_argument("--critic-seeds", type=int, default=4)
    parser.add_argument("--png", type=Path, default=Path("out/results/area_sensor_city100.png"))
    parser.add_argument("--json", type=Path, default=Path("out/results/area_sensor_city100.json"))
    args = parser.parse_args()
    started = time.perf_counter()
    scenes = city100(args.data)
    profile = load_profile(args.profile)
    print(json.dumps(profile.fitted["effects"]["area_sensor"]))
    candidates = {"unpaired profile": profile, "its refused sensor in place (nothing refitted)": with_sensor(profile)}
    cleans = [scenes[scene][0] for scene in HELD_OUT]
    print(f"captures: {widths([scenes[scene][1] for scene in HELD_OUT])}")
    for label, candidate in candidates.items():
        print(f"{label}: {widths(stored(candidate.simulate(cleans, 0)))}", flush=True)
    table = rows(scenes, candidates, args.critic_seeds)
    print(format_table(table))
    columns = {**candidates, "paired built-in": load_profile("city100-iphonex")}
    args.png.parent.mkdir(parents=True, exist_ok=True)
    evidence_page(scenes, dict(zip(("profile", "refused sensor", "paired built-in"), columns.values())), args.png)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(table, indent=2, allow_nan=False) + "\n")
    print(f"wrote {args.png}, {args.json}; {time.perf_counter() - started:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
