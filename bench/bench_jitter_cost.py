"""What the built-in's jitter stage costs a training loop: ``CameraDegrade`` of the built-in with its jitter against
the built-in before it (a profile file), one 224² uint8 image per call, one thread, the two interleaved in blocks
and timed in CPU seconds (so that other jobs on the machine change both alike). Plain script, not a test::

    git show 8cbfe8d:src/camdegrade/profiles/city100-iphonex.safetensors > /tmp/before.safetensors
    .venv/bin/python bench/bench_jitter_cost.py /tmp/before.safetensors
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from camdegrade import CameraDegrade

SIDE = 224
BLOCKS, CALLS = 10, 20


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("before", type=Path, help="the built-in before its jitter (a profile file)")
    parser.add_argument("--profile", default="city100-iphonex")
    args = parser.parse_args()
    torch.set_num_threads(1)
    image = torch.randint(0, 256, (3, SIDE, SIDE), dtype=torch.uint8, generator=torch.Generator().manual_seed(0))
    transforms = {"before": CameraDegrade(args.before, seed=0), "now": CameraDegrade(args.profile, seed=0)}
    for transform in transforms.values():
        for _ in range(CALLS):
            transform(image)
    seconds = dict.fromkeys(transforms, 0.0)
    for _ in range(BLOCKS):
        for name, transform in transforms.items():
            started = time.process_time()
            for _ in range(CALLS):
                transform(image)
            seconds[name] += time.process_time() - started
    for name, spent in seconds.items():
        print(f"{name}: {BLOCKS * CALLS / spent:.1f} images/s ({SIDE}², one image per call, CPU seconds, one thread)")
    print(f"now / before: {seconds['before'] / seconds['now']:.2f}x")


if __name__ == "__main__":
    main()
