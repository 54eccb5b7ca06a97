"""Speed of ``CameraDegrade`` with the grid-free network (``arch="local_affine"``) against the paper's network.

Issue 23's guard: the default architecture's transform must run within 15 % of the paper network's (the speed the
built-ins had before they were refitted with it). Each pair of cases is one paper-network built-in as shipped until
2026-11-27 (kept as test fixtures; its effect stages unchanged) with its network as shipped (the paper's: the CPU
plan, sparse channels and all) and with a :class:`~camdegrade.network.LocalAffineNet` of the same width whose
encoder is the paper network's (so ReLU leaves the same channels at zero); a profile fitted with ``local_affine``
runs exactly this arithmetic. A third case is the built-in of that name as shipped now (its own network and stages:
what a user gets). One 224² uint8 image per call at ``--precision`` (default ``auto``: bfloat16 where the CPU has
it natively), medians of interleaved rounds (see ``bench_transform.interleaved_rates``). The local-affine network
runs with each colour-field upsampling (:data:`~camdegrade.network.FIELD_UPSAMPLING`): ``bilinear`` (the default,
whose time the bound applies to) and ``smooth``, and with the bilinear field and the pointwise curves
(``curves=True``, the fast recipe's since 2026-11-27); the built-in as shipped is also timed without its
frequency-response stage (what that stage costs). Run from the repo root::

    .venv/bin/python bench/bench_arch.py [--quick] [--precision float32]   # writes out/bench/arch.json
"""

from __future__ import annotations

import argparse
import copy
import json
from pathlib import Path

import torch
from bench_transform import Case, Target, cpu_description, interleaved_rates, natural_image

from camdegrade import CameraDegrade, CameraProfile, load_profile
from camdegrade.effects import FrequencyResponse
from camdegrade.network import FIELD_UPSAMPLING, LocalAffineNet

FIXTURES = Path(__file__).resolve().parents[1] / "tests" / "fixtures"
#: Built-in name → the paper-network profile of that name as shipped until 2026-11-27.
PROFILES = {
    "city100-iphonex": FIXTURES / "city100-iphonex-paper.safetensors",
    "city100-iphonex-fast": FIXTURES / "city100-iphonex-fast-paper.safetensors",
}
#: The local-affine transform may take at most this much longer than the paper network's (issue 23).
SLOWDOWN_BOUND = 1.15


def local_affine_twin(profile: CameraProfile, upsample: str = "bilinear", curves: bool = False) -> CameraProfile:
    """``profile`` with a LocalAffineNet of its width, colour-field ``upsample`` and ``curves`` that shares its
    encoder (and its stages)."""
    paper = profile.network
    twin = LocalAffineNet(paper.width, upsample=upsample, curves=curves)
    twin.load_state_dict(
        {**twin.state_dict(), **{k: v for k, v in paper.state_dict().items() if k.startswith("encode")}}
    )
    return CameraProfile(twin.eval(), [copy.deepcopy(effect) for effect in profile.effects], name=f"{profile.name}-la")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer rounds, for a smoke run")
    parser.add_argument("--out", type=Path, default=Path("out/bench/arch.json"))
    parser.add_argument("--precision", default="auto", choices=("auto", "float32", "bfloat16"))
    args = parser.parse_args()
    torch.manual_seed(0)
    image = natural_image()
    cases = {}
    for name, paper_path in PROFILES.items():
        profile = load_profile(paper_path)
        twins = {f"local_affine/{upsample}": local_affine_twin(profile, upsample) for upsample in FIELD_UPSAMPLING}
        twins["local_affine/curves"] = local_affine_twin(profile, curves=True)
        now = load_profile(name)
        without = now.with_chain([effect for effect in now.effects if not isinstance(effect, FrequencyResponse)])
        chosen_cases = (("paper", profile), *twins.items(), ("built-in now", now), ("now without response", without))
        for label, chosen in chosen_cases:
            degrade = CameraDegrade(chosen, seed=0, precision=args.precision)
            cases[f"{name}:{label}"] = Case(lambda degrade=degrade: degrade(image), calls=5 if args.quick else 20)
    rates = interleaved_rates(cases, repeats=3 if args.quick else 9)
    print(f"CPU: {cpu_description()}, {torch.get_num_threads()} threads, precision {args.precision}")
    results, targets = {}, []
    for name in PROFILES:
        paper, local = rates[f"{name}:paper"], rates[f"{name}:local_affine/bilinear"]
        smooth, now = rates[f"{name}:local_affine/smooth"], rates[f"{name}:built-in now"]
        curved, without = rates[f"{name}:local_affine/curves"], rates[f"{name}:now without response"]
        print(
            f"{name:24s} paper {paper:8.1f} img/s   local_affine {local:8.1f} img/s (smooth field {smooth:8.1f}, "
            f"curves {curved:8.1f})   time ratio {paper / local:.3f}   built-in now {now:8.1f} img/s "
            f"(without its frequency response {without:8.1f})"
        )
        results[name] = {
            "paper_images_per_s": paper,
            "local_affine_images_per_s": local,
            "local_affine_smooth_images_per_s": smooth,
            "local_affine_curves_images_per_s": curved,
            "curves_over_plain_time": local / curved,
            "built_in_now_images_per_s": now,
            "time_ratio": paper / local,
            "smooth_over_bilinear_time": local / smooth,
            "built_in_now_over_paper_time": paper / now,
            "built_in_without_response_images_per_s": without,
            "response_over_without_time": without / now,
        }
        targets.append(Target(f"{name}: local_affine time / paper time", paper / local, SLOWDOWN_BOUND, at_most=True))
        targets.append(Target(f"{name}: built-in now / paper built-in time", paper / now, SLOWDOWN_BOUND, at_most=True))
    for target in targets:
        print(target.row())
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"cpu": cpu_description(), "results": results}, indent=1))


if __name__ == "__main__":
    main()
