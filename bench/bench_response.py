"""What caching the frequency-response stage's gain map saves: the stage on one 224² image, its map built once per
gains and size (as a profile runs it) against rebuilt on every call (new gains values each call), and the built-in
``city100-iphonex`` with and without its response stage. Medians of interleaved rounds, one run. Run from the repo
root::

    OMP_NUM_THREADS=2 .venv/bin/python bench/bench_response.py   # writes out/bench/response.json
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import torch
from bench_transform import Case, cpu_description, interleaved_rates, natural_image

from camdegrade import CameraDegrade, load_profile
from camdegrade.effects import FrequencyResponse
from camdegrade.functional import frequency_response_image


def main() -> None:
    torch.manual_seed(0)
    image = natural_image()
    unit = image.float() / 255
    profile = load_profile("city100-iphonex")
    gains = next(effect for effect in profile.effects if isinstance(effect, FrequencyResponse)).gains
    without = profile.with_chain([effect for effect in profile.effects if not isinstance(effect, FrequencyResponse)])
    full, bare = CameraDegrade(profile), CameraDegrade(without)
    fresh = itertools.count(1)  # new gains values on every call: the cache never holds their map
    cases = {
        "stage, map cached": Case(lambda: frequency_response_image(unit, gains), calls=200),
        "stage, map rebuilt": Case(lambda: frequency_response_image(unit, gains * (1 + 1e-6 * next(fresh))), calls=200),
        "built-in": Case(lambda: full(image)),
        "built-in without the stage": Case(lambda: bare(image)),
    }
    with torch.no_grad():
        rates = interleaved_rates(cases, repeats=7)
    cpu = f"{cpu_description()}, {torch.get_num_threads()} threads"
    print(f"CPU: {cpu}")
    for name, rate in rates.items():
        print(f"{name:28s} {1000 / rate:7.3f} ms per image")
    print(
        f"the cache saves {1 - rates['stage, map rebuilt'] / rates['stage, map cached']:.0%} of the stage's time; "
        f"the stage costs {rates['built-in without the stage'] / rates['built-in']:.3f}x the built-in's time"
    )
    out = Path("out/bench/response.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"cpu": cpu, "ms_per_image": {name: 1000 / rate for name, rate in rates.items()}}))


if __name__ == "__main__":
    main()
