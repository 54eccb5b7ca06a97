"""The built-in ``city100-iphonex`` with the fast recipe's last step, ``jitter`` (:mod:`camdegrade.fitting.evidence.
jitter_step`), run as its default fit now runs it after its other steps: the displacement read on the fit's own
training scenes, judged on its own 8 validation scenes (``fitted['validation_scenes']``); then the held-out quality
of ``fit_city100_default.py`` (16 scenes 056–070, 098; 8 critics) written with the profile.

Usage::

    OMP_NUM_THREADS=2 .venv/bin/python experiments/jitter_city100.py --out /tmp/city100-jitter.safetensors
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from fit_city100_default import DEFAULT_DATA, LAST_FITTED_SCENE, held_out_quality

from camdegrade import load_profile
from camdegrade.fitting import FitConfig, PairSet, discover_pairs, filter_pairs
from camdegrade.fitting.steps import run_steps
from camdegrade.fitting.steps.base import PairedFit

#: The fast recipe's steps the built-in's fit did not run, in its order.
REFITTED = ("jitter",)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--profile", default="city100-iphonex", help="a built-in's name or a profile's path")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument(
        "--copy-from", default=None, help="a distilled profile's teacher: its jitter stage copied first, no step run"
    )
    args = parser.parse_args()
    profile = load_profile(args.profile)
    if args.copy_from is not None:
        return copy_jitter(profile, load_profile(args.copy_from), args)
    pairs = filter_pairs(discover_pairs(args.data / "pairs.csv").pairs, subset="city100_iPhoneX")
    validating = set(profile.fitted["validation_scenes"])
    fitted = [pair for pair in pairs if pair.scene <= LAST_FITTED_SCENE]
    held = [pair for pair in pairs if pair.scene > LAST_FITTED_SCENE]
    train = PairSet.load([pair for pair in fitted if pair.scene not in validating])
    val = PairSet.load([pair for pair in fitted if pair.scene in validating])
    started = time.perf_counter()
    fit = PairedFit(train, val, profile=profile, seed=int(profile.fitted["recipe"]["seed"]), say=print)
    run_steps([step for step in FitConfig.recipe("fast").steps if step.name in REFITTED], fit)
    print(f"steps {', '.join(REFITTED)}: {time.perf_counter() - started:.0f} s")
    out = fit.profile
    command = f"python experiments/jitter_city100.py --profile {args.profile} --out {args.out}"
    out.fitted = {**profile.fitted, **fit.records, "jitter_command": command}  # "command" stays the fit's
    out.quality = {**held_out_quality(out, held), "validation": profile.quality.get("validation")}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    out.save(args.out)
    print(json.dumps({key: value for key, value in out.quality.items() if key != "validation"}, indent=1))
    print(f"wrote {args.out}")


def copy_jitter(profile, teacher, args) -> None:
    """``profile`` (distilled from ``teacher``, whose stages it copied) with the teacher's jitter first, as a
    distillation now copies it; the held-out quality measured again."""
    from camdegrade.effects import Jitter
    from camdegrade.fitting.evidence.jitter_step import with_jitter

    stage = next(effect for effect in teacher.effects if isinstance(effect, Jitter))
    pairs = filter_pairs(discover_pairs(args.data / "pairs.csv").pairs, subset="city100_iPhoneX")
    out = with_jitter(profile, stage)
    out.fitted = {**profile.fitted, "jitter": {"copied_from": teacher.name, **teacher.fitted.get("jitter", {})}}
    measured = held_out_quality(out, [pair for pair in pairs if pair.scene > LAST_FITTED_SCENE])
    out.quality = {**profile.quality, **measured, "profile_psnr_sampled_db": measured["profile_psnr_db"]}
    out.save(args.out)
    print(json.dumps(out.quality, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
