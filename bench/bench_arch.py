"""Speed of ``CameraDegrade`` with the grid-free network (``arch="local_affine"``) against the paper's network.

Issue 23's guard: the default architecture's transform must run within 15 % of the paper network's (the speed the
built-ins had before it). Each pair of cases is one built-in profile (its effect stages unchanged) with its network
as shipped (the paper's: the CPU plan, sparse channels and all) and with a :class:`~camdegrade.network.LocalAffineNet`
of the same width whose encoder is the built-in's (so ReLU leaves the same channels at zero); a profile refitted with
``local_affine`` runs exactly this arithmetic. One 224² uint8 image per call, medians of interleaved rounds (see
``bench_transform.interleaved_rates``). The local-affine network runs with each colour-field upsampling
(:data:`~camdegrade.network.FIELD_UPSAMPLING`): ``bilinear`` (the default, whose time the bound applies to) and
``smooth``, so the cost of the smoothing is a ratio of the same run. Run from the repo root::

    .venv/bin/python bench/bench_arch.py [--quick]          # writes out/bench/arch.json
"""

from __future__ import annotations

import argparse
import copy
import json
from pathlib import Path

import torch
from bench_transform import Case, Target, cpu_description, interleaved_rates, natural_image

from camdegrade import CameraDegrade, CameraProfile, load_profile
from camdegrade.network import FIELD_UPSAMPLING, LocalAffineNet

PROFILES = ("city100-iphonex", "city100-iphonex-fast")
#: The local-affine transform may take at most this much longer than the paper network's (issue 23).
SLOWDOWN_BOUND = 1.15


def local_affine_twin(profile: CameraProfile, upsample: str = "bilinear") -> CameraProfile:
    """``profile`` with a LocalAffineNet of its width and colour-field ``upsample`` that shares its encoder (and its
    stages)."""
    paper = profile.network
    twin = LocalAffineNet(paper.width, upsample=upsample)
    twin.load_state_dict(
        {**twin.state_dict(), **{k: v for k, v in paper.state_dict().items() if k.startswith("encode")}}
    )
    return CameraProfile(twin.eval(), [copy.deepcopy(effect) for effect in profile.effects], name=f"{profile.name}-la")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer rounds, for a smoke run")
    parser.add_argument("--out", type=Path, default=Path("out/bench/arch.json"))
    args = parser.parse_args()
    torch.manual_seed(0)
    image = natural_image()
    cases = {}
    for name in PROFILES:
        profile = load_profile(name)
        twins = {f"local_affine/{upsample}": local_affine_twin(profile, upsample) for upsample in FIELD_UPSAMPLING}
        for label, chosen in (("paper", profile), *twins.items()):
            degrade = CameraDegrade(chosen, seed=0)
            cases[f"{name}:{label}"] = Case(lambda degrade=degrade: degrade(image), calls=5 if args.quick else 20)
    rates = interleaved_rates(cases, repeats=3 if args.quick else 9)
    print(f"CPU: {cpu_description()}, {torch.get_num_threads()} threads")
    results, targets = {}, []
    for name in PROFILES:
        paper, local = rates[f"{name}:paper"], rates[f"{name}:local_affine/bilinear"]
        smooth = rates[f"{name}:local_affine/smooth"]
        print(
            f"{name:24s} paper {paper:8.1f} img/s   local_affine {local:8.1f} img/s (smooth field {smooth:8.1f})"
            f"   time ratio {paper / local:.3f}"
        )
        results[name] = {
            "paper_images_per_s": paper,
            "local_affine_images_per_s": local,
            "local_affine_smooth_images_per_s": smooth,
            "time_ratio": paper / local,
            "smooth_over_bilinear_time": local / smooth,
        }
        targets.append(Target(f"{name}: local_affine time / paper time", paper / local, SLOWDOWN_BOUND, at_most=True))
    for target in targets:
        print(target.row())
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"cpu": cpu_description(), "results": results}, indent=1))


if __name__ == "__main__":
    main()
