"""Throughput of CameraDegrade against the paper's network alone and the augmentation chains users pick instead.

Plain script, not a test. Every number is a median over repeated rounds after warm-up, measured in this one run
with the stated number of torch threads; each round times every case in turn, so the machine's drifts in speed hit
all cases alike and the ratios compare like with like. Cases (uint8 224² RGB in, uint8 out):

- ``reference_network_fp32``: the paper's network alone, float32 eager, with the uint8 ↔ float conversion;
- ``camdegrade_single`` / ``camdegrade_batch32``: ``CameraDegrade(profile)`` with its effect stages and the
  automatic precision, one image per call / 32 per call (reported per image); ``camdegrade_single_fp32``: the
  same with ``precision="float32"``; ``camdegrade_single_32px``: one 32² image per call (CIFAR-sized), where the
  fixed cost of a call shows;
- ``torchvision_chain``: v2 ColorJitter + GaussianBlur + GaussianNoise + JPEG;
- ``kornia_chain`` (single and batch 32): ColorJitter + RandomGaussianBlur + RandomGaussianNoise + RandomJPEG;
- ``albumentations_chain``: ColorJitter + GaussianBlur + ISONoise + ImageCompression;
- ``fit_pairs_per_s``: training pairs (224² crops) per second (forward + backward + Adam step, batch 8);
- ``float32_gemm_gflops``: this CPU's float32 matrix-product rate on the shape of the network's largest layer
  (3136×576 by 576×128, GFLOP/s), timed in the same rounds, and ``network_images_per_s_at_gemm_rate``: the
  network's 0.73 GFLOP per 224² image at that rate, about what any float32 arrangement of the network can reach;
- ``diagnose_seconds_100_pairs_256``: wall time of ``camdegrade diagnose`` on 100 pairs of 256² (the CLI).

Peer libraries come from the ``bench`` extra and are skipped when missing. Run from the repo root::

    .venv/bin/python bench/bench_transform.py                 # writes out/bench/transform.json
    .venv/bin/python bench/bench_transform.py --quick         # fewer repeats, for a smoke run
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

os.environ.setdefault("NO_ALBUMENTATIONS_UPDATE", "1")  # albumentations would look for updates online

import torch
import torch.nn.functional as F

from camdegrade import CameraDegrade, load_profile
from camdegrade.effects.chain import apply_effects
from camdegrade.inference import native_bfloat16, resolve_precision, run_network

SIZE = 224


def natural_image(size: int = SIZE) -> torch.Tensor:
    """A 224² uint8 natural photo (scikit-image's astronaut when installed, else smooth generated content)."""
    try:
        from skimage import data

        image = torch.from_numpy(data.astronaut()).permute(2, 0, 1)[None].float()
    except ImportError:
        image = F.interpolate(torch.rand(1, 3, 16, 16, generator=torch.Generator().manual_seed(0)) * 255, size=64)
    return F.interpolate(image, size=(size, size), mode="area")[0].round().clamp(0, 255).to(torch.uint8)


@dataclass
class Case:
    """One measured step: ``calls`` calls per round, each handling ``images_per_call`` images."""

    step: Callable[[], Any]
    images_per_call: int = 1
    calls: int = 30


def interleaved_rates(cases: dict[str, Case], repeats: int, warmup: int = 2) -> dict[str, float]:
    """Median images/s of every case over ``repeats`` rounds, each round timing every case in turn.

    Interleaving matters on shared machines, whose speed drifts by tens of percent within minutes: a slow spell
    then slows every case of a round alike, so the ratios between cases stay right where back-to-back blocks of
    repeats would compare a fast spell with a slow one. Each case's turn starts with ``warmup`` untimed calls, so
    it is not charged for refilling the caches and the heap that the previous case left.
    """
    rates: dict[str, list[float]] = {name: [] for name in cases}
    for _ in range(repeats):
        for name, case in cases.items():
            for _ in range(warmup):
                case.step()
            started = time.perf_counter()
            for _ in range(case.calls):
                case.step()
            rates[name].append(case.calls * case.images_per_call / (time.perf_counter() - started))
    return {name: statistics.median(values) for name, values in rates.items()}


def network_gflop(size: int = SIZE) -> float:
    """GFLOP (2 × multiply-adds) of the paper's network on one ``size``² image: output pixels × fan-in × fan-out."""
    quarter, half = size // 4, size // 2
    conv1 = half**2 * 64 * 3 * 9
    conv2 = quarter**2 * 128 * 64 * 9
    deconv1 = quarter**2 * 128 * 64 * 4
    deconv2 = half**2 * 64 * 3 * 4
    return 2 * (conv1 + conv2 + deconv1 + deconv2) / 1e9


def gemm_case() -> tuple[Case, float]:
    """A float32 matrix product shaped like the network's second convolution, and its GFLOP per call."""
    generator = torch.Generator().manual_seed(0)
    left, right = torch.rand(56 * 56, 576, generator=generator), torch.rand(576, 128, generator=generator)
    out = torch.empty(56 * 56, 128)
    return Case(lambda: torch.mm(left, right, out=out)), 2 * left.shape[0] * left.shape[1] * right.shape[1] / 1e9


def cpu_description() -> str:
    """The CPU's model name (Linux), the vector ISA torch dispatches to, and whether bfloat16 is native."""
    model = platform.processor() or platform.machine()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        names = [line.split(":", 1)[1].strip() for line in cpuinfo.read_text().splitlines() if "model name" in line]
        model = names[0] if names else model
    native = "native bfloat16" if native_bfloat16(torch.device("cpu")) else "no native bfloat16"
    return f"{model}, {torch.backends.cpu.get_cpu_capability()}, {native}"


def reference_network(profile_name: str) -> Callable[[torch.Tensor], torch.Tensor]:
    network = load_profile(profile_name).network

    def run(image: torch.Tensor) -> torch.Tensor:
        with torch.no_grad():
            return network(image[None].float() / 255.0)[0].mul(255).round().clamp(0, 255).to(torch.uint8)

    return run


def torchvision_chain() -> Callable[[torch.Tensor], torch.Tensor]:
    from torchvision.transforms import v2

    return v2.Compose(
        [
            v2.ColorJitter(0.2, 0.2, 0.2, 0.05),
            v2.GaussianBlur(5, sigma=(0.5, 1.5)),
            v2.ToDtype(torch.float32, scale=True),
            v2.GaussianNoise(sigma=0.03),
            v2.ToDtype(torch.uint8, scale=True),
            v2.JPEG((40, 80)),
        ]
    )


def kornia_chain() -> Callable[[torch.Tensor], torch.Tensor] | None:
    try:
        import kornia.augmentation as K
    except ImportError:
        return None
    chain = K.AugmentationSequential(
        K.ColorJitter(0.2, 0.2, 0.2, 0.05, p=1.0),
        K.RandomGaussianBlur((5, 5), (0.5, 1.5), p=1.0),
        K.RandomGaussianNoise(std=0.03, p=1.0),
        K.RandomJPEG(jpeg_quality=(40.0, 80.0), p=1.0),
    )

    def run(images: torch.Tensor) -> torch.Tensor:
        batch = images if images.ndim == 4 else images[None]
        with torch.no_grad():
            return (chain(batch.float() / 255.0).clamp(0, 1) * 255).round().to(torch.uint8)

    return run


def albumentations_chain() -> Callable[[Any], Any] | None:
    try:
        import albumentations as A
    except ImportError:
        return None
    chain = A.Compose(
        [
            A.ColorJitter(0.2, 0.2, 0.2, 0.05, p=1.0),
            A.GaussianBlur(blur_limit=(3, 5), p=1.0),
            A.ISONoise(p=1.0),
            A.ImageCompression(quality_range=(40, 80), p=1.0),
        ]
    )
    return lambda array: chain(image=array)["image"]


def fit_pairs_per_second(repeats: int) -> float:
    from camdegrade.network import DomainShiftNet

    network = DomainShiftNet()
    optimizer = torch.optim.Adam(network.parameters(), lr=0.01)
    clean, captured = torch.rand(8, 3, SIZE, SIZE), torch.rand(8, 3, SIZE, SIZE)

    def step() -> None:
        optimizer.zero_grad(set_to_none=True)
        F.mse_loss(network.forward_aligned(clean), captured).backward()
        optimizer.step()

    return interleaved_rates({"fit": Case(step, images_per_call=8, calls=2)}, repeats, warmup=1)["fit"]


def time_split(degrade: CameraDegrade, image: torch.Tensor, repeats: int) -> dict[str, float]:
    """Milliseconds (medians) of the parts of one single-image call: drawing the params, the network, the effect
    stages, and the whole call (the rest is conversion and the transform's own work). Needs a network."""
    profile = degrade.profile
    unit = image[None].float() / 255.0
    generator = torch.Generator().manual_seed(0)
    with torch.no_grad():
        output = run_network(profile.network, unit, degrade.precision)
        params = profile.make_params(unit.shape, generator)
        parts = {
            "draw_params": lambda: degrade.make_params([image]),
            "network": lambda: run_network(profile.network, unit, degrade.precision),
            "effects": lambda: apply_effects(profile.effects, params, output),
            "whole_call": lambda: degrade(image),
        }
        rates = interleaved_rates({name: Case(step) for name, step in parts.items()}, repeats)
        split = {name: round(1000.0 / rate, 3) for name, rate in rates.items()}
    print("time split (ms per single-image call): " + ", ".join(f"{k} {v:.2f}" for k, v in split.items()))
    return split


def diagnose_time(threads: int) -> float | None:
    """Seconds of ``camdegrade diagnose`` on 100 pairs of 256² (bench_diagnose's timing, run with ``threads``)."""
    from bench_diagnose import timing

    os.environ["OMP_NUM_THREADS"] = str(threads)  # the CLI runs in a child process, which reads this
    result = timing()
    if result["returncode"] != 0:
        print(f"diagnose failed: {result['stderr']}")
        return None
    print(f"{'diagnose_100_pairs_256':28s} {result['seconds']:9.1f} s ({threads} threads)", flush=True)
    return result["seconds"]


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", default="city100-iphonex")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--skip-diagnose", action="store_true", help="leave out the diagnose timing (~1–2 min)")
    parser.add_argument("--out", type=Path, default=Path("out/bench/transform.json"))
    args = parser.parse_args(argv)
    warnings.filterwarnings("ignore")  # peer libraries' deprecation notices are not what is measured
    torch.set_num_threads(args.threads)
    print(f"cpu: {cpu_description()}; {args.threads} torch threads", flush=True)
    repeats, calls = (3, 5) if args.quick else (11, 30)
    image = natural_image()
    batch = image.expand(32, -1, -1, -1).contiguous()
    small = natural_image(32)
    degrade = CameraDegrade(args.profile, seed=0)
    exact = CameraDegrade(args.profile, seed=0, precision="float32")
    batch_calls = max(1, calls // 8)
    reference = reference_network(args.profile)
    cases = {
        "reference_network_fp32": Case(lambda: reference(image), calls=calls),
        "camdegrade_single": Case(lambda: degrade(image), calls=calls),
        "camdegrade_batch32": Case(lambda: degrade(batch), images_per_call=32, calls=batch_calls),
        "camdegrade_single_fp32": Case(lambda: exact(image), calls=calls),
        "camdegrade_single_32px": Case(lambda: degrade(small), calls=calls),
    }
    tv = torchvision_chain()
    cases["torchvision_chain"] = Case(lambda: tv(image), calls=calls)
    kornia = kornia_chain()
    if kornia is not None:
        cases["kornia_chain"] = Case(lambda: kornia(image), calls=calls)
        cases["kornia_chain_batch32"] = Case(lambda: kornia(batch), images_per_call=32, calls=batch_calls)
    album = albumentations_chain()
    if album is not None:
        array = image.permute(1, 2, 0).numpy().copy()
        cases["albumentations_chain"] = Case(lambda: album(array), calls=calls)
    cases["float32_gemm"], gemm_gflop = gemm_case()
    rates = interleaved_rates(cases, repeats)
    gemm_gflops = rates.pop("float32_gemm") * gemm_gflop
    results: dict[str, float | None] = {name: round(rate, 1) for name, rate in rates.items()}
    for name, rate in results.items():
        print(f"{name:28s} {rate:9.1f} images/s", flush=True)
    at_gemm_rate = gemm_gflops / network_gflop()
    print(
        f"float32 matrix products run at {gemm_gflops:.0f} GFLOP/s here; at that rate the network's "
        f"{network_gflop():.2f} GFLOP per image take {1000 / at_gemm_rate:.1f} ms ({at_gemm_rate:.0f} images/s), "
        "before effects and conversions"
    )
    split = time_split(degrade, image, repeats) if degrade.profile.network is not None else None
    results["fit_pairs_per_s"] = round(fit_pairs_per_second(repeats), 2)
    print(f"{'fit_pairs_per_s':28s} {results['fit_pairs_per_s']:9.2f} pairs/s (224² crops, batch 8)")
    diagnose_seconds = None if args.skip_diagnose else diagnose_time(args.threads)

    single = results["camdegrade_single"]
    ratios = {
        "single_vs_reference_network": single / results["reference_network_fp32"],
        "single_vs_torchvision_chain": single / results["torchvision_chain"],
        "batch32_vs_single": results["camdegrade_batch32"] / single,
    }
    if album is not None:
        ratios["single_vs_albumentations_chain"] = single / results["albumentations_chain"]
    if kornia is not None:
        ratios["single_vs_kornia_chain"] = single / results["kornia_chain"]
    print("ratios: " + ", ".join(f"{k} {v:.2f}x" for k, v in ratios.items()))
    record = {
        "images_per_s": results,
        "diagnose_seconds_100_pairs_256": diagnose_seconds,
        "single_call_split_ms": split,
        "float32_gemm_gflops": round(gemm_gflops, 1),
        "network_gflop_per_image": round(network_gflop(), 3),
        "network_images_per_s_at_gemm_rate": round(at_gemm_rate, 1),
        "ratios": {k: round(v, 3) for k, v in ratios.items()},
        "profile": args.profile,
        "effects": load_profile(args.profile).effect_names,
        "precision_auto_resolves_to": resolve_precision("auto", torch.device("cpu")),
        "threads": args.threads,
        "image": f"uint8 3x{SIZE}x{SIZE}",
        "peak_rss_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__}",
        "cpu": cpu_description(),
        "repeats": repeats,
        "quick": args.quick,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=2) + "\n")
    print(f"peak RSS {record['peak_rss_mib']} MiB; wrote {args.out}")
    return record


if __name__ == "__main__":
    main()
