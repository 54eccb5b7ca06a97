"""The learned stage's gate against its own noise on City100's unpaired split (issue 43): for each split of the
fitting sets into halves A and B (``-1``: alternate images, as the gate splits them; ``n >= 0``: a random split of
seed ``1000 + n``), a stage trained on A after the unpaired profile is judged on B
(:func:`~camdegrade.fitting.two_sample.gate.judge_learned_stage`: the statistics, the fresh critic, the split-half
standard error of the statistics' change), and the change is read on 8 random halves of the judging images too.
Run from the repo root (the unpaired profile from ``experiments/fit_city100_unpaired.py``)::

    OMP_NUM_THREADS=1 .venv/bin/python experiments/two_sample_gate_spread.py PROFILE -1 0 [1 ...]

Prints one JSON line per split and appends it to ``out/results/two_sample_gate_spread.jsonl``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from two_sample_city100 import CAPTURED_SCENES, CLEAN_SCENES, DEFAULT_DATA, ROOT, city100

from camdegrade import load_profile
from camdegrade.effects.base import evenly_spaced
from camdegrade.fitting.two_sample.gate import JUDGE_IMAGES, judge_learned_stage, set_statistics, statistics_distance
from camdegrade.fitting.two_sample.train import fit_two_sample


def halves(items: list, split: int) -> tuple[list, list]:
    """Half A and half B of ``items``: alternate ones for ``split`` -1, else a random split of seed 1000 + split."""
    if split < 0:
        return items[0::2], items[1::2]
    order = torch.randperm(len(items), generator=torch.Generator().manual_seed(1000 + split)).tolist()
    return [items[i] for i in order[::2]], [items[i] for i in order[1::2]]


def content_spread(named, stage, cleans: list, captures: list) -> dict:
    """The statistics' change (with the stage less without) on 8 random half-splits of the judging images, and its
    standard error from them."""
    cleans, captures = evenly_spaced(cleans, JUDGE_IMAGES), evenly_spaced(captures, JUDGE_IMAGES)
    sims = {
        label: profile.simulate(cleans, 0, stream="two-sample-gate", eight_bit=True)
        for label, profile in (("without", named), ("with", named.with_effects(stage)))
    }
    generator, changes = torch.Generator().manual_seed(123), []
    for _ in range(8):
        i = torch.randperm(len(cleans), generator=generator).tolist()
        j = torch.randperm(len(captures), generator=generator).tolist()
        for part, real in ((i[: len(i) // 2], j[: len(j) // 2]), (i[len(i) // 2 :], j[len(j) // 2 :])):
            reals = [captures[k] for k in real]
            distance = {k: statistics_distance(set_statistics([v[x] for x in part], reals)) for k, v in sims.items()}
            changes.append(round(distance["with"] - distance["without"], 4))
    pairs = torch.tensor(changes).view(-1, 2)
    error = float(((pairs[:, 0] - pairs[:, 1]) / 2).pow(2).mean().sqrt())  # as judges.split_half_error
    return {"changes_on_halves": changes, "change_error": round(error, 4)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("profile", type=Path, help="the unpaired profile of the split")
    parser.add_argument("splits", type=int, nargs="+")
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "results" / "two_sample_gate_spread.jsonl")
    args = parser.parse_args(argv)
    scenes = city100(args.data)
    named = load_profile(args.profile)
    cleans = [scenes[scene][0] for scene in CLEAN_SCENES]
    captures = [scenes[scene][1] for scene in CAPTURED_SCENES]
    args.json.parent.mkdir(parents=True, exist_ok=True)
    for split in args.splits:
        (clean_a, clean_b), (capture_a, capture_b) = halves(cleans, split), halves(captures, split)
        started = time.perf_counter()
        stage, _ = fit_two_sample(named, clean_a, capture_a, seed=0, steps=1200)
        judgement = judge_learned_stage(named, stage, clean_b, capture_b, seed=0, critic_seeds=2)
        record = {
            "split": split,
            "seconds": round(time.perf_counter() - started, 1),
            "judgement": judgement.to_dict(),
            "change": round(judgement.with_stage["distance"] - judgement.without["distance"], 4),
            **content_spread(named, stage, clean_b, capture_b),
        }
        print(json.dumps(record), flush=True)
        with args.json.open("a") as file:
            file.write(json.dumps(record) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
