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
- ``float32_gemm`` (and ``bfloat16_gemm`` where native): this CPU's matrix-product rate on the shape of the network's
  largest layer (3136×576 by 576×128, GFLOP/s), timed in the same rounds: at that rate the network's 0.73 GFLOP per
  224² image is about what any arrangement of the network in that precision can reach;
- ``diagnose_seconds_100_pairs_256``: wall time of ``camdegrade diagnose`` on 100 pairs of 256² (the CLI);
- ``camdegrade_fast_single``: the built-in fast profile (``city100-iphonex-fast``, width 32), one image per call;
- ``network_plan``: the profile's network alone as the transform runs it (uint8 in, float32 out), beside the
  matrix-product line of the precision it runs in (``bfloat16_gemm`` where bfloat16 is native, else float32);
- ``fit_step_before`` / ``fit_step``: training crops per second at 128², batch 32, forward + backward + Adam step:
  the module in float32 on NCHW crops (how fits ran before) and the fit's own step (channels-last crops, bfloat16
  autocast where native).

The end of the output is a table of targets (issues 46 and 18), each measured in this run, with PASS or FAIL, the
CPU and the machine's load averages (a shared machine's speed drifts: read the ratios, each the median of the
per-round ratios of two cases timed in the same round, with their range over the rounds).

Peer libraries come from the ``bench`` extra and are skipped when missing. Run from the repo root::

    .venv/bin/python bench/bench_transform.py                 # writes out/bench/transform.json
    .venv/bin/python bench/bench_transform.py --quick         # fewer repeats, for a smoke run
"""

from __future__ import annotations

import argparse
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
from machine import cpu_description, load_text, write_json

from camdegrade import CameraDegrade, list_profiles, load_profile
from camdegrade.effects.chain import apply_effects
from camdegrade.effects.plan import FilterRun, chain_plan
from camdegrade.network.inference import native_bfloat16, resolve_precision, run_network

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
    rounds = interleaved_round_rates(cases, repeats, warmup)
    return {name: statistics.median(values) for name, values in rounds.items()}


def interleaved_round_rates(cases: dict[str, Case], repeats: int, warmup: int = 2) -> dict[str, list[float]]:
    """Images/s of every case in each of ``repeats`` interleaved rounds (see :func:`interleaved_rates`)."""
    rates: dict[str, list[float]] = {name: [] for name in cases}
    for _ in range(repeats):
        for name, case in cases.items():
            for _ in range(warmup):
                case.step()
            started = time.perf_counter()
            for _ in range(case.calls):
                case.step()
            rates[name].append(case.calls * case.images_per_call / (time.perf_counter() - started))
    return rates


def round_ratios(rounds: dict[str, list[float]], case: str, reference: str) -> list[float] | None:
    """``case``'s rate over ``reference``'s, round by round (both timed in the same round: a ratio a slow spell of
    the machine moves least); ``None`` when either was not measured."""
    if case not in rounds or reference not in rounds:
        return None
    return [ours / theirs for ours, theirs in zip(rounds[case], rounds[reference], strict=True)]


def network_gflop(size: int = SIZE) -> float:
    """GFLOP (2 × multiply-adds) of the paper's network on one ``size``² image: output pixels × fan-in × fan-out."""
    quarter, half = size // 4, size // 2
    conv1 = half**2 * 64 * 3 * 9
    conv2 = quarter**2 * 128 * 64 * 9
    deconv1 = quarter**2 * 128 * 64 * 4
    deconv2 = half**2 * 64 * 3 * 4
    return 2 * (conv1 + conv2 + deconv1 + deconv2) / 1e9


def gemm_case(dtype: torch.dtype = torch.float32) -> tuple[Case, float]:
    """A matrix product shaped like the network's second convolution in ``dtype``, and its GFLOP per call."""
    generator = torch.Generator().manual_seed(0)
    left = torch.rand(56 * 56, 576, generator=generator).to(dtype)
    right = torch.rand(576, 128, generator=generator).to(dtype)
    out = torch.empty(56 * 56, 128, dtype=dtype)
    return Case(lambda: torch.mm(left, right, out=out)), 2 * left.shape[0] * left.shape[1] * right.shape[1] / 1e9


def fit_step_cases() -> dict[str, Case]:
    """Training at 128², batch 32: the module in float32 on NCHW crops (before) and the fit's own step."""
    from camdegrade.fitting.network.training import _TrainStep
    from camdegrade.fitting.recipe import FitConfig
    from camdegrade.network import DomainShiftNet

    generator = torch.Generator().manual_seed(0)
    clean, captured = torch.rand(32, 3, 128, 128, generator=generator), torch.rand(32, 3, 128, 128, generator=generator)
    before_net, new_net = DomainShiftNet(), DomainShiftNet()
    before_optimizer = torch.optim.Adam(before_net.parameters(), lr=0.001)
    step = _TrainStep(new_net, torch.optim.Adam(new_net.parameters(), lr=0.001), FitConfig(), "cpu", 1)

    def before() -> None:
        before_optimizer.zero_grad(set_to_none=True)
        F.mse_loss(before_net(clean), captured).backward()
        before_optimizer.step()

    return {
        "fit_step_before": Case(before, images_per_call=32, calls=2),
        "fit_step": Case(lambda: step(clean, captured, 32), images_per_call=32, calls=2),
    }


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


def time_split(degrade: CameraDegrade, image: torch.Tensor, repeats: int) -> dict[str, float]:
    """Milliseconds (medians) of the parts of one single-image call: drawing the params, the network (on the uint8
    image, as the transform runs it), the effect stages together and each step of the chain's plan (a composed
    filter of adjacent linear stages, ``blur+sharpen``, or a stage), and the whole call (the rest is conversion and
    the transform's own work). Needs a network."""
    profile = degrade.profile
    batch = image[None]
    generator = torch.Generator().manual_seed(0)
    with torch.no_grad():
        output = run_network(profile.network, batch, degrade.precision)
        params = profile.make_params(batch.shape, generator)
        parts = {
            "draw_params": lambda: degrade.make_params([image]),
            "network": lambda: run_network(profile.network, batch, degrade.precision),
            "effects": lambda: apply_effects(profile.effects, params, output),
        }
        for step in chain_plan(profile.effects).steps:
            indices = step.indices if isinstance(step, FilterRun) else (step,)
            effects, drawn = [profile.effects[i] for i in indices], [params[i] for i in indices]
            label = "+".join(effect.name for effect in effects)
            parts[label] = lambda effects=effects, drawn=drawn: apply_effects(effects, drawn, output)
        parts["whole_call"] = lambda: degrade(image)
        rates = interleaved_rates({name: Case(step) for name, step in parts.items()}, repeats)
        split = {name: round(1000.0 / rate, 3) for name, rate in rates.items()}
    shown = ", ".join(f"{name} {ms:.2f}" for name, ms in split.items())
    print(f"time split of {profile.name} (ms per single-image call): {shown}")
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


#: The profile of width 32 distilled from the default one (``experiments/distill_city100.py``).
FAST_PROFILE = "city100-iphonex-fast"


@dataclass
class Target:
    """One target (issues 18 and 46): a value measured in this run against its bound; for a ratio of rates, the
    median of its per-round ratios and their range (``spread``)."""

    name: str
    measured: float | None
    bound: float
    at_most: bool = False  # the measured value must not exceed the bound (else: reach it)
    spread: tuple[float, float] | None = None

    @classmethod
    def of_rounds(cls, name: str, ratios: list[float] | None, bound: float) -> Target:
        if not ratios:
            return cls(name, None, bound)
        return cls(name, statistics.median(ratios), bound, spread=(min(ratios), max(ratios)))

    @property
    def passed(self) -> bool | None:
        if self.measured is None:
            return None
        return self.measured <= self.bound if self.at_most else self.measured >= self.bound

    def row(self) -> str:
        verdict = {True: "PASS", False: "FAIL", None: "n/a"}[self.passed]
        shown = "not measured" if self.measured is None else f"{self.measured:.3f}"
        spread = "" if self.spread is None else f"  (rounds {self.spread[0]:.2f}–{self.spread[1]:.2f})"
        return f"{self.name:64s} {shown:>12s}   {'<=' if self.at_most else '>='} {self.bound:<6g} {verdict}{spread}"


def transform_cases(args: argparse.Namespace, image: torch.Tensor, calls: int) -> tuple[dict[str, Case], Any]:
    """CameraDegrade (full and fast profile), its network alone, and the peer chains, one image per call."""
    batch = image.expand(32, -1, -1, -1).contiguous()
    degrade = CameraDegrade(args.profile, seed=0)
    exact = CameraDegrade(args.profile, seed=0, precision="float32")
    reference = reference_network(args.profile)
    network = degrade.profile.network
    plain, small = image[None], natural_image(32)
    cases = {
        "reference_network_fp32": Case(lambda: reference(image), calls=calls),
        "network_plan": Case(lambda: run_network(network, plain, degrade.precision), calls=calls),
        "camdegrade_single": Case(lambda: degrade(image), calls=calls),
        "camdegrade_batch32": Case(lambda: degrade(batch), images_per_call=32, calls=max(1, calls // 8)),
        "camdegrade_single_fp32": Case(lambda: exact(image), calls=calls),
        "camdegrade_single_32px": Case(lambda: degrade(small), calls=calls),
    }
    if FAST_PROFILE in list_profiles():
        fast = CameraDegrade(FAST_PROFILE, seed=0)
        cases["camdegrade_fast_single"] = Case(lambda: fast(image), calls=calls)
    tv = torchvision_chain()
    cases["torchvision_chain"] = Case(lambda: tv(image), calls=calls)
    kornia = kornia_chain()
    if kornia is not None:
        cases["kornia_chain"] = Case(lambda: kornia(image), calls=calls)
    album = albumentations_chain()
    if album is not None:
        array = image.permute(1, 2, 0).numpy().copy()
        cases["albumentations_chain"] = Case(lambda: album(array), calls=calls)
    return cases, degrade


def line_cases() -> tuple[dict[str, Case], dict[str, float]]:
    """The matrix-product lines (float32, and bfloat16 where native) and their GFLOP per call."""
    cases, gflop = {}, {}
    cases["float32_gemm"], gflop["float32_gemm"] = gemm_case(torch.float32)
    if native_bfloat16(torch.device("cpu")):
        cases["bfloat16_gemm"], gflop["bfloat16_gemm"] = gemm_case(torch.bfloat16)
    return cases, gflop


def fast_profile_quality() -> float | None:
    """How far the fast profile's held-out City100 mean PSNR lies below the full one's (dB), as recorded when it was
    made (``experiments/distill_city100.py``)."""
    if FAST_PROFILE not in list_profiles():
        return None
    quality = load_profile(FAST_PROFILE).quality
    if "full_profile_psnr_mean_db" not in quality:
        return None
    return quality["full_profile_psnr_mean_db"] - quality["profile_psnr_mean_db"]


def targets(
    rates: dict[str, float], rounds: dict[str, list[float]], lines: dict[str, float], diagnose_seconds: float | None
) -> list[Target]:
    """Issue 46's targets (the built-ins against the torchvision and albumentations chains, medians of the per-round
    ratios) and issue 18's, from this run's rates (images/s, crops/s), their rounds and lines (GFLOP/s)."""
    network_ms, call_ms = 1000 / rates["network_plan"], 1000 / rates["camdegrade_single"]
    line = lines.get("bfloat16_gemm", lines["float32_gemm"])
    plan_share = rates["network_plan"] / (line / network_gflop())
    return [
        Target.of_rounds(
            "46. city100-iphonex single 224² / torchvision chain",
            round_ratios(rounds, "camdegrade_single", "torchvision_chain"),
            1.0,
        ),
        Target.of_rounds(
            "46. city100-iphonex-fast single 224² / torchvision chain",
            round_ratios(rounds, "camdegrade_fast_single", "torchvision_chain"),
            2.0,
        ),
        Target.of_rounds(
            "46. city100-iphonex-fast single 224² / albumentations chain",
            round_ratios(rounds, "camdegrade_fast_single", "albumentations_chain"),
            1.0,
        ),
        Target("18.1 everything beyond the network, share of a single 224² call", 1 - network_ms / call_ms, 0.20, True),
        Target("18.1 network plan, share of its matrix-product line", plan_share, 0.85),
        Target("18.2 fast profile held-out City100 mean PSNR below the full (dB)", fast_profile_quality(), 0.3, True),
        Target(
            "18.3 training crops/s at 128²: the fit's step / before", rates["fit_step"] / rates["fit_step_before"], 2.0
        ),
        Target("diagnose, 100 pairs of 256² (s)", diagnose_seconds, 120.0, True),
    ]


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
    print(f"cpu: {cpu_description()}; {args.threads} torch threads; {load_text()}", flush=True)
    repeats, calls = (3, 5) if args.quick else (11, 30)
    image = natural_image()
    cases, degrade = transform_cases(args, image, calls)
    gemms, gemm_gflop = line_cases()
    rounds = interleaved_round_rates({**cases, **gemms, **fit_step_cases()}, repeats)
    rates = {name: statistics.median(values) for name, values in rounds.items()}
    lines = {name: rates.pop(name) * gemm_gflop[name] for name in gemms}
    for name, rate in rates.items():
        unit = "crops/s" if name.startswith("fit_step") else "images/s"
        print(f"{name:28s} {rate:9.1f} {unit}", flush=True)
    for name, gflops in lines.items():
        print(
            f"{name:28s} {gflops:9.1f} GFLOP/s: the network's {network_gflop():.2f} GFLOP per 224² image would take "
            f"{1000 * network_gflop() / gflops:.2f} ms at this rate",
            flush=True,
        )
    split = time_split(degrade, image, repeats) if degrade.profile.network is not None else None
    fast = CameraDegrade(FAST_PROFILE, seed=0) if FAST_PROFILE in list_profiles() else None
    fast_split = time_split(fast, image, repeats) if fast is not None else None
    diagnose_seconds = None if args.skip_diagnose else diagnose_time(args.threads)
    checks = targets(rates, rounds, lines, diagnose_seconds)
    print(f"\ntargets (issues 46 and 18; ratios measured in this run, on {cpu_description()}; {load_text()}):")
    for check in checks:
        print("  " + check.row())
    single = rates["camdegrade_single"]
    ratios = {
        "single_vs_reference_network": single / rates["reference_network_fp32"],
        "single_vs_torchvision_chain": single / rates["torchvision_chain"],
        "batch32_vs_single": rates["camdegrade_batch32"] / single,
    }
    for peer in ("albumentations_chain", "kornia_chain"):
        if peer in rates:
            ratios[f"single_vs_{peer}"] = single / rates[peer]
            if "camdegrade_fast_single" in rates:
                ratios[f"fast_single_vs_{peer}"] = rates["camdegrade_fast_single"] / rates[peer]
    print("ratios: " + ", ".join(f"{k} {v:.2f}x" for k, v in ratios.items()))
    record = {
        "images_per_s": {name: round(rate, 1) for name, rate in rates.items()},
        "gemm_gflops": {name: round(value, 1) for name, value in lines.items()},
        "targets": [
            {
                "name": c.name,
                "measured": c.measured,
                "bound": c.bound,
                "at_most": c.at_most,
                "passed": c.passed,
                "rounds_range": c.spread,
            }
            for c in checks
        ],
        "load_average_1_5_15": list(os.getloadavg()),
        "diagnose_seconds_100_pairs_256": diagnose_seconds,
        "single_call_split_ms": split,
        "fast_single_call_split_ms": fast_split,
        "network_gflop_per_image": round(network_gflop(), 3),
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
    print(f"peak RSS {record['peak_rss_mib']} MiB")
    write_json(args.out, record)
    return record


if __name__ == "__main__":
    main()
