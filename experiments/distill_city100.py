"""Make the built-in ``city100-iphonex-fast``: the ``city100-iphonex`` network distilled into a network of width 32
(about a quarter of its arithmetic), its effect stages copied but its frequency response refitted on its own output;
held-out numbers beside the full profile's.

The student learns from the full profile's network on clean images only (no captures): the clean City100 images
of the scenes the full profile was fitted on (001–055), read in place from ``../shared/data/real-pairs``. Its last
stage, the frequency response, matches a network's output to the captures' spectrum, so it is fitted again for the
student (``camdegrade.fitting.steps.response``, on the captures of the full profile's training scenes, judged on its
validation scenes); ``--teacher-response`` keeps the copied one. The 16
held-out scenes (056–070, 098) are used only for the numbers: mean PSNR/SSIM (noise stage skipped) and sampled
PSNR against the REAL captures, for both profiles, as ``experiments/city100_evidence.py`` reports them. Run from the
repo root::

    .venv/bin/python experiments/distill_city100.py --out src/camdegrade/profiles/city100-iphonex-fast.safetensors
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from city100_evidence import DEFAULT_DATA, HELD_OUT, TRAIN, evaluate, load_scenes

from camdegrade import CameraProfile, load_profile
from camdegrade.effects import FrequencyResponse
from camdegrade.fitting import FitConfig, distill_profile
from camdegrade.fitting.steps import PairedFit
from camdegrade.fitting.steps.response import ResponseMatch
from camdegrade.pairs import PairSet


def refit_response(
    fast: CameraProfile, teacher: CameraProfile, scenes: list[str], cleans: list, captures: list, seed: int
) -> CameraProfile:
    """``fast`` with its frequency response fitted on its own network's output (the copied one was fitted on the
    teacher's), on the teacher's training scenes and judged on its validation scenes."""
    validation = set(teacher.fitted.get("validation_scenes", []))
    pairs = list(zip(scenes, cleans, captures, strict=True))
    train = [(clean, captured) for scene, clean, captured in pairs if scene not in validation]
    val = [(clean, captured) for scene, clean, captured in pairs if scene in validation]
    without = fast.with_chain([effect for effect in fast.effects if not isinstance(effect, FrequencyResponse)])
    fit = PairedFit(PairSet.load(train), PairSet.load(val), without, seed, print)
    note = ResponseMatch().run(fit)
    fit.profile.fitted = {**fast.fitted, "response": note}
    return fit.profile


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--out", type=Path, default=Path("out/city100-iphonex-fast.safetensors"))
    parser.add_argument("--width", type=int, default=32)
    parser.add_argument("--epochs", type=int, default=80)
    parser.add_argument("--patience", type=int, default=0, help="early stopping (0: run every epoch)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--teacher-response", action="store_true", help="keep the full profile's response as copied")
    args = parser.parse_args(argv)

    started = time.perf_counter()
    teacher = load_profile("city100-iphonex")
    scenes, train_clean, train_captured = load_scenes(args.data, TRAIN)
    images = [(image * 255).round().to(torch.uint8) for image in train_clean]
    fast = distill_profile(
        teacher,
        images,
        width=args.width,
        recipe=FitConfig.recipe("fast", epochs=args.epochs, patience=args.patience),
        seed=args.seed,
        name="city100-iphonex-fast",
        callback=lambda r: print(f"epoch {r.epoch:3d}  lr {r.lr:.5f}  student vs teacher {r.val_psnr:.2f} dB"),
        log=print,
    )
    if not args.teacher_response:
        fast = refit_response(fast, teacher, scenes, train_clean, train_captured, args.seed)
    _, held_clean, held_captured = load_scenes(args.data, HELD_OUT)
    full_numbers = evaluate(teacher, held_clean, held_captured, args.seed)
    fast_numbers = evaluate(fast, held_clean, held_captured, args.seed)
    minutes = (time.perf_counter() - started) / 60
    fast.fitted["images"] = "clean City100 iPhone X images of scenes 001-055 (the full profile's fitting scenes)"
    fast.fitted["command"] = (
        f"python experiments/distill_city100.py --out {args.out} --width {args.width} --epochs {args.epochs} "
        f"--patience {args.patience} --seed {args.seed}" + (" --teacher-response" if args.teacher_response else "")
    )
    fast.fitted["total_minutes"] = round(minutes, 1)
    fast.quality = {
        **fast.quality,
        "held_out_pairs": len(held_clean),
        "held_out": "City100 iPhone X scenes 056-070, 098 (REAL captures; never used)",
        "profile_psnr_mean_db": fast_numbers["psnr_mean"],
        "profile_ssim_mean": fast_numbers["ssim_mean"],
        "profile_psnr_sampled_db": fast_numbers.get("psnr_sampled"),
        "full_profile_psnr_mean_db": full_numbers["psnr_mean"],
        "full_profile_ssim_mean": full_numbers["ssim_mean"],
    }
    fast.save(args.out)
    print(json.dumps({"full": full_numbers, "fast": fast_numbers}, indent=2))
    gap = full_numbers["psnr_mean"] - fast_numbers["psnr_mean"]
    print(
        f"held-out mean PSNR: full {full_numbers['psnr_mean']:.3f} dB, fast {fast_numbers['psnr_mean']:.3f} dB "
        f"({gap:+.3f} dB below; target within 0.3 dB)"
    )
    print(f"wrote {args.out} ({minutes:.1f} min)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
