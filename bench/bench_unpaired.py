"""Time of an unpaired fit (issue 27): 100 captures of 512² and 100 clean images of other scenes, every stage.

Plain script, not a test. The captures are dead-leaves scenes (:mod:`camdegrade.synthetic`) photographed by a
simulated camera (blur, vignetting, noise, white balance, a tone curve), written as JPEG files at quality 85 so
that the codec stage is read from their tables; the clean set is 100 other dead-leaves scenes. The target is at
most 10 minutes on 2 cores with the default stages, the learned texture step included (two half-trainings, their
judgements and, where both keep it, a training on all; issue 43); with ``--no-learned``, without it, at most 5
minutes (issue 27). Run from the repo root::

    OMP_NUM_THREADS=2 .venv/bin/python bench/bench_unpaired.py [--count 100] [--size 512] [--no-learned]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import torch
from bench_cli import cpu_name
from machine import write_json
from PIL import Image

from camdegrade import CameraProfile
from camdegrade._support.pixels import unit_to_bytes
from camdegrade.effects import Blur, Color, Noise, Tone, Vignetting
from camdegrade.fitting.unpaired import UNPAIRED_EFFECTS, fit_unpaired
from camdegrade.synthetic import dead_leaves_images

CAMERA = CameraProfile(
    None,
    [
        Blur(1.2),
        Vignetting(-0.3),
        Noise(levels=torch.full((3, 4), 3.0 / 255), linear=False),
        Color(torch.diag(torch.tensor([1.15, 1.0, 0.85]))),
        Tone(gamma=1.2),
    ],
)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--count", type=int, default=100)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--json", type=Path, default=Path("out/bench/unpaired.json"))
    parser.add_argument("--no-learned", action="store_true", help="without the learned texture step")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        captured, clean = Path(folder, "captured"), Path(folder, "clean")
        captured.mkdir()
        clean.mkdir()
        scenes = dead_leaves_images(args.count, args.size, seed=2)
        for index, image in enumerate(CAMERA.simulate(scenes, seed=7)):
            Image.fromarray(unit_to_bytes(image).permute(1, 2, 0).numpy()).save(
                captured / f"{index:03d}.jpg", quality=85
            )
        for index, image in enumerate(dead_leaves_images(args.count, args.size, seed=1)):
            Image.fromarray(image.permute(1, 2, 0).numpy()).save(clean / f"{index:03d}.png")
        effects = [name for name in UNPAIRED_EFFECTS if name != "learned_texture" or not args.no_learned]
        started, cpu = time.perf_counter(), time.process_time()
        profile = fit_unpaired(captured, clean, effects=effects, progress=True)
        seconds, cpu_seconds = time.perf_counter() - started, time.process_time() - cpu
    result = {
        "captures": args.count,
        "size": args.size,
        "seconds": round(seconds, 1),
        # CPU time of all threads: on a machine shared with other jobs the wall time is an upper bound, and an idle
        # machine of as many cores as threads needs at least cpu_seconds / threads.
        "cpu_seconds": round(cpu_seconds, 1),
        "threads": torch.get_num_threads(),
        "cpu": cpu_name(),
        "torch": torch.__version__,
        "kept": profile.effect_names,
    }
    if args.no_learned:
        result["within_5_minutes"] = seconds <= 300
    else:
        result["learned"] = profile.fitted["effects"].get("learned_texture")
        result["within_10_minutes"] = seconds <= 600
    print(json.dumps(result, indent=2))
    write_json(args.json, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
