"""Issue 43's paired option on City100: the built-in ``city100-iphonex`` with and without the paired fit's learned
texture step (``fit --learned-texture critic``: :class:`~camdegrade.fitting.steps.learned.LearnedTexturePaired`), on
the 16 held-out scenes.

The step runs as the paired fit runs it, on the built-in's own split of scenes 001–055 (its recorded
``validation_scenes`` validate, the other 47 train; unaligned, as the built-in was fitted): trained on the training
pairs (1,200 steps, L2 weight 100, seed 0) and judged by its gate on the validation pairs. Both rows are then measured
on the held-out pairs 056–070 and 098 (whole frames, seed 0, 8-bit) with ``two_sample_city100.rows`` (band log2 power,
flat-noise ratio, sampled PSNR, image-only critic repeated: 2 critics per seed) and the conditional mean's PSNR. The
"with" row is the stage whatever the gate said (the gate's verdict is printed and recorded). Run from the repo root::

    OMP_NUM_THREADS=1 .venv/bin/python experiments/paired_learned_city100.py --out /tmp/city100-paired-learned.json \
        --png /tmp/city100-paired-learned.png

It writes the JSON (rows, the step's record, seconds wall and CPU) and a PNG (clean | capture | built-in |
built-in + stage: flat at 1:1, texture at 2×).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from fidelity_report import real_pairs_parser
from fit_city100_unpaired import DEFAULT_DATA, HELD_OUT
from fit_city100_unpaired import city100 as city100_bytes
from torch import Tensor
from two_sample_city100 import PAIRED_SCENES, city100, evidence_page, format_table, rows, stored

from camdegrade import CameraProfile, load_profile
from camdegrade.fitting.steps.base import PairedFit
from camdegrade.fitting.steps.learned import LearnedTexturePaired
from camdegrade.measures.metrics import psnr
from camdegrade.pairs.pairset import PairSet


def paired_fit(scenes: dict[str, tuple[Tensor, Tensor]], built_in: CameraProfile) -> PairedFit:
    """The built-in's fit state as its own fit left it (``scenes``: uint8 pairs): its validation scenes validate, the
    rest of 001–055 train."""
    validation = set(built_in.fitted["validation_scenes"])
    pairs = PairSet([scenes[s] for s in PAIRED_SCENES], list(PAIRED_SCENES), list(PAIRED_SCENES))
    train = pairs.subset([i for i, s in enumerate(PAIRED_SCENES) if s not in validation])
    val = pairs.subset([i for i, s in enumerate(PAIRED_SCENES) if s in validation])
    return PairedFit.of(pairs, train, val, profile=built_in, seed=0, say=lambda line: print(line, flush=True))


def mean_psnr(scenes: dict, profile: CameraProfile) -> float:
    """The conditional mean's PSNR (8-bit) against the held-out captures."""
    cleans = [scenes[scene][0] for scene in HELD_OUT]
    means = stored(profile.simulate(cleans, 0, deterministic=True))
    return round(sum(psnr(mean, scenes[s][1]) for mean, s in zip(means, HELD_OUT, strict=True)) / len(HELD_OUT), 3)


def main(argv: list[str] | None = None) -> int:
    parser = real_pairs_parser(__doc__, DEFAULT_DATA)
    parser.add_argument("--critic-seeds", type=int, default=4)
    parser.add_argument("--out", type=Path, required=True, help="the JSON written")
    parser.add_argument("--png", type=Path, default=None)
    args = parser.parse_args(argv)
    if not (args.data / "pairs.csv").is_file():
        parser.error(f"no pairs.csv in {args.data}; pass --data with the real-pairs folder")
    scenes = city100(args.data)
    built_in = load_profile("city100-iphonex")
    fit, step = paired_fit(city100_bytes(args.data), built_in), LearnedTexturePaired()
    started, cpu = time.perf_counter(), time.process_time()
    proposal = step.propose(fit)
    trained = {"seconds": round(time.perf_counter() - started, 1), "cpu_seconds": round(time.process_time() - cpu, 1)}
    record = step.judge(fit, proposal)
    trained["with_gate_seconds"] = round(time.perf_counter() - started, 1)
    trained["with_gate_cpu_seconds"] = round(time.process_time() - cpu, 1)
    print(f"step: {trained}; gate: {record}", flush=True)
    candidates = {"built-in city100-iphonex": built_in, "built-in + learned stage": built_in.with_effects(proposal[0])}
    table = rows(scenes, candidates, args.critic_seeds)
    for row, profile in zip(table, candidates.values(), strict=True):
        row["psnr_mean"] = mean_psnr(scenes, profile)
        print(f"{row['row']}: PSNR sampled {row['psnr']:.2f}, mean {row['psnr_mean']:.2f}", flush=True)
    print(format_table(table))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    result = {"step": record, "times": trained, "rows": table, "critic_seeds": args.critic_seeds}
    args.out.write_text(json.dumps(result, indent=2, allow_nan=False) + "\n")
    if args.png is not None:
        evidence_page(scenes, {name: profile for name, profile in candidates.items()}, args.png)
        print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
