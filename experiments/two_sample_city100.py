"""Issue 43's measurement: does a learned texture stage, trained by a two-sample objective after the named stages,
make City100's unpaired profile harder to tell from the iPhone X's captures?

The unpaired split of ``experiments/fit_city100_unpaired.py``: the fit sees the clean images of scenes 001–035 and the
captures of 036–055 (no scene on both sides); the check uses the pairs of the 16 held-out scenes (056–070, 098),
whole frames, each simulation with seed = scene index, stored as 8-bit values. Rows: the clean image, the built-in
``city100-iphonex`` (the paired fit), today's unpaired profile (:func:`~camdegrade.fitting.unpaired.fit_unpaired`),
the same with the learned stage (:func:`~camdegrade.fitting.two_sample.gate.fit_learned_stage`: trained on each
half of the fitting sets and judged on the other half; without ``--no-gate`` it is kept only where both halves say
so) and, with ``--paired``, the built-in with a learned stage trained on its own training pairs 001–055 with an L2
term (``pixel_weight``). Columns: :mod:`camdegrade.measures.fidelity` (band log2 power, flat-noise ratio, paired
PSNR) and the image-only critic repeated (:func:`~camdegrade.measures.critic.repeated_critic_test`, 2 critics per
seed). Run from the repo root::

    OMP_NUM_THREADS=2 .venv/bin/python experiments/two_sample_city100.py [--critic-seeds 4] [--steps 1200] \
        [--paired] [--polyu] [--unpaired PROFILE]

It writes ``docs/two_sample_city100.png`` (clean | capture | unpaired before | unpaired now | paired built-in, flat
at 1:1 and textured at 2×) and ``out/results/two_sample_city100.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from fidelity_report import band_cell, band_heading, best_window, labelled_grid, number, real_pairs_parser, save_png
from fit_city100_unpaired import CAPTURED_SCENES, CLEAN_SCENES, DEFAULT_DATA, HELD_OUT, ROOT, SHOWN, TILE
from fit_city100_unpaired import city100 as city100_bytes
from PIL import Image
from torch import Tensor

from camdegrade import CameraProfile, load_profile
from camdegrade._support.pixels import as_unit, unit_to_bytes
from camdegrade.fitting.two_sample.gate import StageTraining, fit_learned_stage
from camdegrade.fitting.two_sample.train import TwoSampleOptions, fit_two_sample
from camdegrade.fitting.unpaired import fit_unpaired
from camdegrade.functional.analysis.images import flat_mask, gradient_energy
from camdegrade.measures.critic import repeated_critic_test
from camdegrade.measures.fidelity import measure_fidelity

PAIRED_SCENES = [f"{n:03d}" for n in range(1, 56)]


def city100(data: Path) -> dict[str, tuple[Tensor, Tensor]]:
    """scene → (clean, captured), float in [0, 1], of the City100 iPhone X pairs."""
    return {scene: tuple(as_unit(image) for image in pair) for scene, pair in city100_bytes(data).items()}


def stored(images: list[Tensor]) -> list[Tensor]:
    return [image.mul(255).round().div(255) for image in images]


def unpaired_profile(scenes: dict, path: Path | None) -> tuple[CameraProfile, float | None]:
    """Today's unpaired profile of the split, fitted (and timed), or read from ``path`` (no time)."""
    if path is not None:
        return load_profile(path), None
    started = time.perf_counter()
    profile = fit_unpaired(
        [scenes[scene][1] for scene in CAPTURED_SCENES],
        [scenes[scene][0] for scene in CLEAN_SCENES],
        progress=True,
        name="city100-iphonex-unpaired",
    )
    return profile, time.perf_counter() - started


def learned(scenes: dict, named: CameraProfile, args: argparse.Namespace) -> tuple[CameraProfile, dict]:
    """``named`` with the learned stage of the unpaired split (gated unless ``--no-gate``), and its record."""
    cleans = [scenes[scene][0] for scene in CLEAN_SCENES]
    captures = [scenes[scene][1] for scene in CAPTURED_SCENES]
    options = TwoSampleOptions(**json.loads(args.options))
    started = time.perf_counter()
    if args.no_gate:
        stage, evidence = fit_two_sample(
            named, cleans, captures, seed=args.seed, steps=args.steps, options=options, progress=True
        )
        evidence = {"kept": True, "gated": False, "trainings": [evidence]}
    else:
        training = StageTraining(seed=args.seed, steps=args.steps, options=options)
        stage, evidence = fit_learned_stage(named, cleans, captures, training)
    evidence["seconds"] = round(time.perf_counter() - started, 1)
    return (named.with_effects(stage) if stage is not None else named), evidence


def learned_paired(scenes: dict, args: argparse.Namespace) -> tuple[CameraProfile, dict]:
    """The built-in with a learned stage trained on its own training pairs, L2 term on (``pixel_weight``)."""
    built_in = load_profile("city100-iphonex")
    options = TwoSampleOptions(**{"pixel_weight": 100.0, **json.loads(args.options)})
    cleans = [scenes[scene][0] for scene in PAIRED_SCENES]
    captures = [scenes[scene][1] for scene in PAIRED_SCENES]
    stage, evidence = fit_two_sample(
        built_in, cleans, captures, steps=args.steps, options=options, paired=True, progress=True
    )
    return built_in.with_effects(stage), evidence


def rows(scenes: dict, candidates: dict[str, CameraProfile | None], critic_seeds: int) -> list[dict]:
    """Each row's fidelity and repeated image-only critic on the held-out pairs."""
    cleans = [scenes[scene][0] for scene in HELD_OUT]
    reals = [scenes[scene][1] for scene in HELD_OUT]
    out = []
    for label, profile in candidates.items():
        sims = cleans if profile is None else stored(profile.simulate(cleans, 0))
        report = measure_fidelity(sims, reals, cleans).to_dict(digits=3)
        critic = repeated_critic_test((cleans, reals, sims), HELD_OUT, critic_seeds, image_only=True)
        out.append({"row": label, **report, "critic_image_only": critic.to_dict()})
        print(f"{label}: {critic.describe()}", flush=True)
    return out


def format_table(table: list[dict]) -> str:
    lines = [
        f"| simulation | {band_heading()} | flat-noise ratio | PSNR dB | critic image-only |",
        "|---|---|---|---|---|",
    ]
    for row in table:
        critic = row["critic_image_only"]
        spread = f"{critic['accuracy']:.3f} ± {critic['std']:.2f} [{min(critic['accuracies']):.2f}–"
        spread += f"{max(critic['accuracies']):.2f}] ({critic['critics']} critics)"
        cells = [row["row"], band_cell(row["bands"]), number(row["noise_ratio"]), f"{row['psnr']:.2f}", spread]
        lines.append(f"| {' | '.join(cells)} |")
    return "\n".join(lines)


def evidence_page(scenes: dict, columns: dict[str, CameraProfile | None], path: Path) -> None:
    """clean | capture | each profile's simulation of :data:`SHOWN`: the flattest window at 1:1, the most textured
    at 2× nearest-neighbour."""
    lines = []
    for scene in SHOWN:
        clean, real = scenes[scene]
        seed = HELD_OUT.index(scene)
        images = [clean, real] + [stored(p.simulate([clean], seed))[0] for p in columns.values() if p is not None]
        windows = (("flat 1:1", flat_mask(clean), TILE), ("texture 2x", gradient_energy(clean), TILE // 2))
        for kind, score, side in windows:
            top, left = best_window(score, side)
            crops = [unit_to_bytes(image[:, top : top + side, left : left + side]) for image in images]
            tiles = [Image.fromarray(c.permute(1, 2, 0).numpy()).resize((TILE, TILE), Image.NEAREST) for c in crops]
            lines.append((f"{scene} {kind}", tiles))
    names = ["clean", "capture", *[name for name, p in columns.items() if p is not None]]
    save_png(labelled_grid(names, lines, TILE, header=28), path)


def main(argv: list[str] | None = None) -> int:
    parser = real_pairs_parser(__doc__, DEFAULT_DATA)
    parser.add_argument("--unpaired", type=Path, help="today's unpaired profile of the split, already fitted")
    parser.add_argument("--steps", type=int, default=1200)
    parser.add_argument("--seed", type=int, default=0, help="the learned stage's training seed")
    parser.add_argument("--options", default="{}", help="TwoSampleOptions fields as JSON")
    parser.add_argument("--no-gate", action="store_true", help="train once on all fitting images, keep the stage")
    parser.add_argument("--paired", action="store_true", help="also the built-in + a stage trained on its pairs")
    parser.add_argument("--critic-seeds", type=int, default=4)
    parser.add_argument(
        "--no-references", action="store_true", help="leave out the clean-image and built-in rows (measured before)"
    )
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "city100-unpaired-learned.safetensors")
    parser.add_argument("--png", type=Path, default=ROOT / "docs" / "two_sample_city100.png")
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "results" / "two_sample_city100.json")
    args = parser.parse_args(argv)
    if not (args.data / "pairs.csv").is_file():
        parser.error(f"no pairs.csv in {args.data}; pass --data with the real-pairs folder")
    scenes = city100(args.data)
    unpaired, unpaired_seconds = unpaired_profile(scenes, args.unpaired)
    now, record = learned(scenes, unpaired, args)
    print(f"learned stage: kept {record['kept']}, {record['seconds']} s", flush=True)
    now.save(args.out)
    built_in = load_profile("city100-iphonex")
    candidates = {
        "clean image unchanged": None,
        "paired fit (built-in city100-iphonex)": built_in,
        "unpaired fit (today)": unpaired,
        "unpaired fit + learned texture stage": now,
    }
    if args.no_references:
        candidates = {key: value for key, value in candidates.items() if key.startswith("unpaired")}
    if args.paired:
        candidates["paired built-in + learned stage (trained paired)"], record["paired"] = learned_paired(scenes, args)
    table = rows(scenes, candidates, args.critic_seeds)
    print(format_table(table))
    evidence_page(scenes, {"unpaired before": unpaired, "unpaired now": now, "paired built-in": built_in}, args.png)
    print(f"wrote {args.png}")
    times = {"unpaired_fit_s": None if unpaired_seconds is None else round(unpaired_seconds, 1)}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    result = {"times": times, "learned": record, "rows": table, "options": args.options, "steps": args.steps}
    result["seed"] = args.seed
    args.json.write_text(json.dumps(result, indent=2, allow_nan=False) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
