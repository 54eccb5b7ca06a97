"""Throughput of DegradedDataset against the bare dataset, and of BatchDegrade, in images per second.

Plain script, not a test. For each setting it iterates a DataLoader once per repeat (after warm-up epochs, with
persistent workers, so worker start-up is not timed) and reports the median images/s. Settings:

- ``bare``: the in-memory dataset alone (uint8 images already decoded, so loading costs almost nothing);
- ``wrapper_p0``: ``DegradedDataset(..., Bernoulli(0.0))``: the wrapper's own bookkeeping, nothing degraded;
- ``bernoulli_p0.5`` / ``union``: half of the returned images degraded on the CPU in the loader;
- ``batch_p0.5``: the bare loader, then ``BatchDegrade(p=0.5)`` on the collated batch (CPU, and CUDA if present).

Run from the repo root::

    .venv/bin/python bench/bench_data.py                     # writes out/bench/data.json
    .venv/bin/python bench/bench_data.py --quick             # fewer items and repeats, for smoke runs
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from torch.utils.data import DataLoader, Dataset

import camdegrade
from camdegrade import CameraProfile, DomainShiftNet, load_profile
from camdegrade.data import BatchDegrade, Bernoulli, DegradedDataset, IndexedDataset, Union
from camdegrade.errors import ProfileError


class InMemoryImages(Dataset):
    """``items`` random uint8 images ``(3, size, size)`` with integer labels, generated once."""

    def __init__(self, items: int, size: int) -> None:
        generator = torch.Generator().manual_seed(0)
        self.images = torch.randint(0, 256, (items, 3, size, size), dtype=torch.uint8, generator=generator)

    def __len__(self) -> int:
        return self.images.shape[0]

    def __getitem__(self, index: int) -> tuple[torch.Tensor, int]:
        return self.images[index].clone(), index % 10


def bench_profile() -> CameraProfile:
    """The built-in City100 profile when it ships, else a network-only profile with fixed random weights."""
    try:
        return load_profile("city100-iphonex")
    except ProfileError:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(0)
            return CameraProfile(DomainShiftNet(), name="bench-network-only")


def time_epochs(run_epoch: Callable[[], int], warmup: int, repeats: int) -> dict[str, Any]:
    for _ in range(warmup):
        run_epoch()
    seconds, images = [], 0
    for _ in range(repeats):
        start = time.perf_counter()
        images = run_epoch()
        seconds.append(time.perf_counter() - start)
    median = statistics.median(seconds)
    return {"images": images, "seconds": [round(s, 4) for s in seconds], "images_per_s": round(images / median, 1)}


def loader_epoch(loader: DataLoader) -> Callable[[], int]:
    def run() -> int:
        return sum(batch[0].shape[0] for batch in loader)

    return run


def batch_epoch(loader: DataLoader, batch_degrade: BatchDegrade, device: torch.device) -> Callable[[], int]:
    def run() -> int:
        count = 0
        for indices, (images, _) in loader:
            out = batch_degrade(images.to(device, non_blocking=True), indices)
            count += out.shape[0]
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        return count

    return run


def make_loader(dataset: Dataset, workers: int, batch_size: int) -> DataLoader:
    return DataLoader(dataset, batch_size=batch_size, num_workers=workers, persistent_workers=workers > 0)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--items", type=int, default=256)
    parser.add_argument("--size", type=int, default=64, help="image side in pixels")
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--workers", type=int, nargs="+", default=[0, 2])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--warmup", type=int, default=1)
    parser.add_argument("--threads", type=int, default=1, help="torch threads in the main process")
    parser.add_argument("--quick", action="store_true", help="64 items, 2 repeats")
    parser.add_argument("--out", type=Path, default=Path("out/bench/data.json"))
    args = parser.parse_args(argv)
    if args.quick:
        args.items, args.repeats = 64, 2
    torch.set_num_threads(args.threads)

    profile = bench_profile()
    bare = InMemoryImages(args.items, args.size)
    datasets = {
        "bare": bare,
        "wrapper_p0": DegradedDataset(bare, profile, Bernoulli(0.0), seed=0),
        "bernoulli_p0.5": DegradedDataset(bare, profile, Bernoulli(0.5), seed=0),
        "union": DegradedDataset(bare, profile, Union(), seed=0),
    }
    results = []
    for workers in args.workers:
        for name, dataset in datasets.items():
            loader = make_loader(dataset, workers, args.batch_size)
            results.append(
                {"name": name, "workers": workers, **time_epochs(loader_epoch(loader), args.warmup, args.repeats)}
            )
            print(f"{name:>16}  workers={workers}  {results[-1]['images_per_s']:>9.1f} images/s", flush=True)
        devices = [torch.device("cpu")] + ([torch.device("cuda")] if torch.cuda.is_available() else [])
        for device in devices:
            batch_degrade = BatchDegrade(profile, p=0.5, seed=0)
            loader = make_loader(IndexedDataset(bare), workers, args.batch_size)
            timing = time_epochs(batch_epoch(loader, batch_degrade, device), args.warmup, args.repeats)
            results.append({"name": f"batch_p0.5_{device.type}", "workers": workers, **timing})
            print(f"{results[-1]['name']:>16}  workers={workers}  {timing['images_per_s']:>9.1f} images/s", flush=True)

    rate = {(r["name"], r["workers"]): r["images_per_s"] for r in results}
    overhead = {
        f"{name}_workers{workers}": round(rate[("bare", workers)] / rate[(name, workers)], 2)
        for (name, workers) in rate
        if name != "bare"
    }
    report = {
        "camdegrade": camdegrade.__version__,
        "torch": torch.__version__,
        "python": platform.python_version(),
        "cpu_count": os.cpu_count(),
        "main_threads": torch.get_num_threads(),
        "worker_threads": 1,
        "profile": profile.name,
        "image": [3, args.size, args.size],
        "items": args.items,
        "batch_size": args.batch_size,
        "repeats": args.repeats,
        "warmup": args.warmup,
        "results": results,
        "slowdown_vs_bare": overhead,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"slowdown vs bare (bare images/s ÷ setting images/s): {json.dumps(overhead)}")
    print(f"wrote {args.out}")
    return report


if __name__ == "__main__":
    main()
