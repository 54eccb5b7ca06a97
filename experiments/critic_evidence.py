"""What gives the simulation away to the learned critic (issues 23 and 24)?

On the 16 held-out City100 iPhone X scenes (056–070, 098; never used in any fit), whole frames, the critic of
:mod:`camdegrade.measures.critic` is trained on 8 scenes and scored on the other 8, image-only (what a model
trained on the simulation sees) and paired (it also sees the clean source), for every row below and for several
critic seeds (a seed draws the patches, the critic's start and its minibatches), so that a difference between two
rows can be set against the spread between seeds:

- clean source; built-in (the paper-network ``city100-iphonex`` shipped until 2026-11-27, ``PAPER_BUILT_IN``,
  sampled with seed = scene index); its network alone;
  built-in + unsharp mask (σ 1, amount 0.5); blur + 12-number colour map (an affine RGB map, least squares, after
  :meth:`Blur.fit <camdegrade.effects.Blur.fit>`; both fitted on scenes 001–055);
- ablations of the built-in, each testing what the critic keys on: its 4×4-periodic grid removed (the per-phase mean
  of ``Y − box9(Y)`` over the frame, :func:`~camdegrade.measures.fidelity.grid_phases`, taken off every channel);
  each channel's histogram matched to the capture's (an oracle: it reads the capture of the same scene); no noise
  stage; the noise stage's std doubled; its effects (blur σ 0.79, noise, tone) without the network; the sampled
  built-in blurred once more (σ 1, about the blur of the fitted row in all); its network run at four diagonal
  shifts of the 4-pixel period and averaged (:func:`phase_averaged`), then its effects; and that blurred once more.

Every image is rounded to 8 bits, as the captures are. It prints the table (per row the grid RMS and the 4-pixel
edge modulation of :func:`edge_modulation`, then per critic the mean over seeds, the seeds' spread, the mean
bootstrap interval over held-out pairs and the difference from the built-in per seed), each row's accuracy on flat,
mid and textured patches, the built-in critic's accuracy by group (:mod:`camdegrade.measures.critic.explain`,
pooled over seeds), and writes the surest patches of the built-in's image-only critic (seed 0) with the fine
detail it saw to ``docs/critic_city100.png``. Run from the repo root::

    OMP_NUM_THREADS=1 .venv/bin/python experiments/critic_evidence.py [--data DIR] [--seeds 3] [--steps 250]

The critics are seeded, but torch trains them differently with another number of threads (seed 1 of the
built-in: 0.935 with one thread, 0.914 with two): keep ``OMP_NUM_THREADS=1`` to reproduce these numbers.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade import CameraDegrade, CameraProfile, load_profile
from camdegrade._support.pixels import as_unit, unit_to_bytes
from camdegrade.effects import Blur
from camdegrade.fitting import discover_pairs, filter_pairs, load_pair
from camdegrade.functional.analysis.images import luma
from camdegrade.functional.optics.blur import blur_image
from camdegrade.measures.critic import STEPS
from camdegrade.measures.critic.explain import GROUPINGS, explained_critic_test, surest_png
from camdegrade.measures.fidelity import GRID_PERIOD, grid_phases, grid_rms

ROOT = Path(__file__).resolve().parents[1]
#: The built-in city100-iphonex as shipped until 2026-11-27 (the paper's network + blur, noise, tone), which this
#: evidence is about; the built-in has been a local-affine fit since.
PAPER_BUILT_IN = Path(__file__).resolve().parents[1] / "tests" / "fixtures" / "city100-iphonex-paper.safetensors"
DEFAULT_DATA = ROOT.parent / "shared" / "data" / "real-pairs"
TRAINING = [f"{n:03d}" for n in range(1, 56)]
HELD_OUT = sorted({f"{n:03d}" for n in range(56, 71)} | {"098"})
UNSHARP_SIGMA, UNSHARP_AMOUNT = 1.0, 0.5
BASELINE = "built-in"
SUREST = 8
#: At most this many of the surest patches of each class from one held-out scene.
SUREST_PER_SCENE = 2
EXTRA_BLUR = 1.0
#: The fine detail (image minus its 3×3 mean) is shown as 0.5 + DETAIL_GAIN · detail.
DETAIL_GAIN = 4.0
MODES = {"image-only": True, "paired": False}


def city100_pairs(data: Path, scenes: list[str]) -> list[tuple[str, Tensor, Tensor]]:
    """``(scene, clean, real)`` uint8 for the City100 iPhone X ``scenes``."""
    found = {p.scene: p for p in filter_pairs(discover_pairs(data / "pairs.csv").pairs, subset="city100_iPhoneX")}
    return [(scene, *load_pair(found[scene])) for scene in scenes]


def unsharp(unit: Tensor) -> Tensor:
    """``image + amount · (image − blur_σ(image))``, float in [0, 1]."""
    return (unit + UNSHARP_AMOUNT * (unit - blur_image(unit, UNSHARP_SIGMA))).clamp(0, 1)


def without_grid(unit: Tensor) -> Tensor:
    """``unit`` less its frame-mean 4×4-periodic luma pattern (the same on every channel), float in [0, 1]. Taken
    off before rounding to 8 bits: the pattern is a fraction of a level, which rounding an 8-bit image would undo."""
    pattern = grid_phases(unit)[0].float() / 255.0
    height, width = unit.shape[-2:]
    tiled = pattern.repeat(-(-height // GRID_PERIOD), -(-width // GRID_PERIOD))[:height, :width]
    return (unit - tiled).clamp(0, 1)


def phase_averaged(clean: Tensor, profile: CameraProfile, seed: int) -> Tensor:
    """``profile`` with its network run on the clean image shifted by 0–3 pixels diagonally (edges replicated) and
    shifted back, the four outputs averaged, then its effects: every column and row meets the network's 4-pixel
    period at each phase once, so what depends on that phase averages out (a shift-invariant network would give
    its own output back)."""
    unit = as_unit(clean)[None]
    network = CameraDegrade(profile.with_chain([]), seed=seed)
    outputs = []
    for shift in range(GRID_PERIOD):
        padded = F.pad(unit, (shift, GRID_PERIOD - shift, shift, GRID_PERIOD - shift), mode="replicate")
        outputs.append(network(padded)[..., shift : shift + unit.shape[-2], shift : shift + unit.shape[-1]])
    averaged = torch.stack(outputs).mean(0)
    return CameraDegrade(CameraProfile(None, profile.effects), seed=seed)(averaged)[0].clamp(0, 1)


def edge_modulation(image: Tensor) -> float:
    """How much the mean absolute luma step between neighbouring pixels depends on the position of the step in a
    4-pixel period: the largest over the smallest of the four per-phase means (columns and rows, averaged); 1 for a
    camera, whose pixels sit on no period. Two stride-2 transposed convolutions make some steps sharper than
    others."""
    gray = luma(as_unit(image)) * 255.0
    ratios = []
    for steps in (gray.diff(dim=-1).abs(), gray.diff(dim=-2).abs().T):
        usable = steps.shape[-1] - steps.shape[-1] % GRID_PERIOD
        phases = steps[:, :usable].reshape(steps.shape[0], -1, GRID_PERIOD).mean((0, 1))
        ratios.append(float(phases.max() / phases.min()))
    return sum(ratios) / len(ratios)


def histogram_matched(image: Tensor, target: Tensor) -> Tensor:
    """Each uint8 channel of ``image`` mapped so that its histogram is ``target``'s (same pixel count): every level
    takes the mean of the target's sorted values over the ranks the level holds."""
    out = torch.empty_like(image)
    for channel in range(3):
        levels = image[channel].flatten().long()
        ends = torch.bincount(levels, minlength=256).cumsum(0)
        starts = torch.cat([ends.new_zeros(1), ends[:-1]])
        sums = torch.cat(
            [torch.zeros(1, dtype=torch.float64), target[channel].flatten().double().sort().values.cumsum(0)]
        )
        means = (sums[ends] - sums[starts]) / (ends - starts).clamp_min(1)
        out[channel] = means.round().clamp(0, 255).to(torch.uint8)[levels].reshape(image.shape[1:])
    return out


def fit_blur_and_colour_map(training: list[tuple[str, Tensor, Tensor]]) -> tuple[Blur, Tensor]:
    """:meth:`Blur.fit` of clean → capture, then the affine RGB map ``[3, 4]`` (12 numbers) that takes the blurred
    clean image to the capture by least squares on 4×-area-averaged pixels (averaging removes noise and small
    misalignment, which a colour map cannot explain)."""
    cleans = [as_unit(clean) for _, clean, _ in training]
    reals = [as_unit(real) for _, _, real in training]
    blur = Blur.fit(cleans, reals)
    rows, targets = [], []
    with torch.no_grad():
        for clean, real in zip(cleans, reals, strict=True):
            blurred = F.avg_pool2d(blur(clean[None]), 4)[0].reshape(3, -1).T
            rows.append(torch.cat([blurred, torch.ones(len(blurred), 1)], 1).double())
            targets.append(F.avg_pool2d(real[None], 4)[0].reshape(3, -1).T.double())
    solution = torch.linalg.lstsq(torch.cat(rows), torch.cat(targets)).solution  # [4, 3]
    return blur, solution.T.float()


def blurred_and_mapped(clean: Tensor, blur: Blur, colour_map: Tensor) -> Tensor:
    with torch.no_grad():
        unit = blur(as_unit(clean)[None])[0]
    mapped = torch.einsum("ij,jhw->ihw", colour_map[:, :3], unit) + colour_map[:, 3, None, None]
    return mapped.clamp(0, 1)


def rows_of(held_out: list[tuple[str, Tensor, Tensor]], blur: Blur, colour_map: Tensor) -> dict[str, list[Tensor]]:
    """Every row's uint8 image of each held-out clean image (profiles sampled with seed = scene index)."""
    built_in = load_profile(PAPER_BUILT_IN)
    noise = next(effect for effect in built_in.effects if effect.name == "noise")
    quiet = built_in.with_chain([effect for effect in built_in.effects if effect.name != "noise"])
    effects_alone = CameraProfile(None, built_in.effects)
    loud = built_in.with_chain([noise.scaled(4.0) if effect is noise else effect for effect in built_in.effects])
    rows: dict[str, list[Tensor]] = {}
    for index, (_, clean, real) in enumerate(held_out):
        # sampled in float (the same bytes as from uint8, once rounded); every change is made before rounding
        sampled = CameraDegrade(built_in, seed=index)(as_unit(clean)).clamp(0, 1)
        averaged = phase_averaged(clean, built_in, index)
        images = {
            "clean source": clean,
            BASELINE: sampled,
            "network alone": CameraDegrade(built_in.with_chain([]), seed=index)(clean),
            "built-in + unsharp": unsharp(sampled),
            "blur + colour map": blurred_and_mapped(clean, blur, colour_map),
            "built-in, grid removed": without_grid(sampled),
            "built-in, histogram matched": histogram_matched(unit_to_bytes(sampled), real),
            "built-in, no noise": CameraDegrade(quiet, seed=index)(clean),
            "built-in, noise std x2": CameraDegrade(loud, seed=index)(clean),
            "built-in effects, no network": CameraDegrade(effects_alone, seed=index)(clean),
            "built-in + blur σ1": blur_image(sampled, EXTRA_BLUR).clamp(0, 1),
            "built-in, network phase-averaged": averaged,
            "built-in, network phase-averaged, + blur σ1": blur_image(averaged, EXTRA_BLUR).clamp(0, 1),
        }
        for name, image in images.items():
            rows.setdefault(name, []).append(image if image.dtype == torch.uint8 else unit_to_bytes(image))
    return rows


def image_measures(held_out, rows: dict[str, list[Tensor]]) -> dict[str, dict[str, float]]:
    """Per row (and the captures), mean over the frames of the grid RMS (levels) and the 4-pixel edge modulation."""
    frames = {"capture": [real for _, _, real in held_out], **rows}
    return {
        name: {
            "grid": statistics.mean(grid_rms(as_unit(image)) for image in images),
            "modulation": statistics.mean(edge_modulation(image) for image in images),
        }
        for name, images in frames.items()
    }


def run_critics(held_out, rows, seeds: int, steps: int) -> tuple[dict, dict]:
    """Per row, mode and seed: the critic's result and its explanation."""
    cleans = [as_unit(clean) for _, clean, _ in held_out]
    reals = [as_unit(real) for _, _, real in held_out]
    fit, check = slice(0, None, 2), slice(1, None, 2)
    results, explained = {}, {}
    for name, images in rows.items():
        sims = [as_unit(image) for image in images]
        for mode, image_only in MODES.items():
            for seed in range(seeds):
                result, explanation = explained_critic_test(
                    (cleans[fit], reals[fit], sims[fit]),
                    (cleans[check], reals[check], sims[check]),
                    seed,
                    steps,
                    image_only=image_only,
                    k=SUREST,
                    per_pair=SUREST_PER_SCENE,
                )
                results.setdefault(name, {}).setdefault(mode, []).append(result)
                explained.setdefault(name, {}).setdefault(mode, []).append(explanation)
            accuracies = " ".join(f"{r.accuracy:.3f}" for r in results[name][mode])
            print(f"  {name}, {mode}: {accuracies}", flush=True)
    return results, explained


def _spread(values: list[float]) -> str:
    deviation = statistics.stdev(values) if len(values) > 1 else 0.0
    return f"{statistics.mean(values):.3f} ± {deviation:.3f}"


def format_table(results: dict, measured: dict) -> str:
    """Grid RMS and edge modulation; then per mode the mean accuracy ± std over seeds, the seeds' own values, the
    mean bootstrap interval, and the per-seed difference from the built-in (mean, min to max)."""
    header = "| image | grid | edge modulation | " + " | ".join(
        f"{mode} (seeds) | {mode} 95 % CI | {mode} − built-in" for mode in MODES
    )
    capture = measured["capture"]
    lines = [
        header + " |",
        "|---" * (3 + 3 * len(MODES)) + "|",
        f"| capture | {capture['grid']:.3f} | {capture['modulation']:.3f} |" + " |" * (3 * len(MODES)),
    ]
    for name, modes in results.items():
        cells = [f"{measured[name]['grid']:.3f}", f"{measured[name]['modulation']:.3f}"]
        for mode in MODES:
            runs = modes[mode]
            accuracies = [r.accuracy for r in runs]
            seeds = "/".join(f"{a:.2f}" for a in accuracies)
            interval = f"{statistics.mean(r.low for r in runs):.2f}–{statistics.mean(r.high for r in runs):.2f}"
            deltas = [a - b.accuracy for a, b in zip(accuracies, results[BASELINE][mode], strict=True)]
            delta = (
                "—"
                if name == BASELINE
                else f"{statistics.mean(deltas):+.3f} ({min(deltas):+.2f} to {max(deltas):+.2f})"
            )
            cells += [f"{_spread(accuracies)} ({seeds})", interval, delta]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def pooled_groups(explanations: list) -> dict[str, dict[str, dict]]:
    """Accuracy and patch count per group, pooled over the seeds' critics (each seed's terciles its own)."""
    out: dict[str, dict[str, dict]] = {}
    for grouping, (_, names) in GROUPINGS.items():
        out[grouping] = {}
        for name in names:
            counted = [e.groups[grouping][name] for e in explanations if e.groups[grouping][name]["patches"]]
            patches = sum(g["patches"] for g in counted)
            correct = sum(g["accuracy"] * g["patches"] for g in counted)
            out[grouping][name] = {"accuracy": correct / patches if patches else None, "patches": patches}
    return out


def format_texture(explained: dict) -> str:
    """Per row and mode, the accuracy on the flat, mid and textured third of the patches, pooled over seeds."""
    lines = ["| image | " + " | ".join(f"{mode} flat / mid / textured" for mode in MODES) + " |", "|---|---|---|"]
    for name, modes in explained.items():
        cells = []
        for mode in MODES:
            groups = pooled_groups(modes[mode])["texture"]
            cells.append(" / ".join(f"{value['accuracy']:.2f}" for value in groups.values()))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def format_groups(explained: dict) -> str:
    lines = ["| built-in critic | grouping | low tercile | mid tercile | high tercile |", "|---|---|---|---|---|"]
    for mode, explanations in explained.items():
        for grouping, groups in pooled_groups(explanations).items():
            cells = [f"{name} {value['accuracy']:.3f} ({value['patches']})" for name, value in groups.items()]
            lines.append(f"| {mode} | {grouping} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--seeds", type=int, default=3, help="critic seeds per row and mode (default 3)")
    parser.add_argument("--steps", type=int, default=STEPS, help=f"critic training steps (default {STEPS})")
    parser.add_argument("--png", type=Path, default=ROOT / "docs" / "critic_city100.png")
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "results" / "critic_city100.json")
    args = parser.parse_args(argv)
    if not (args.data / "pairs.csv").is_file():
        parser.error(f"no pairs.csv in {args.data}; pass --data with the real-pairs folder")
    if args.seeds < 1 or args.steps < 1:
        parser.error(f"--seeds and --steps must be positive, got {args.seeds} and {args.steps}")
    started = time.perf_counter()
    blur, colour_map = fit_blur_and_colour_map(city100_pairs(args.data, TRAINING))
    print(f"blur + colour map fitted on {len(TRAINING)} scenes: {blur}, map {colour_map.tolist()}", flush=True)
    held_out = city100_pairs(args.data, HELD_OUT)
    rows = rows_of(held_out, blur, colour_map)
    measured = image_measures(held_out, rows)
    print(f"fit, rows and image measures: {time.perf_counter() - started:.0f} s", flush=True)
    results, explained = run_critics(held_out, rows, args.seeds, args.steps)
    print(f"{args.seeds * len(MODES) * len(rows)} critics: {time.perf_counter() - started:.0f} s in all", flush=True)
    print(format_table(results, measured))
    print()
    print(format_texture(explained))
    print()
    print(format_groups(explained[BASELINE]))
    names = HELD_OUT[1::2]
    title = (
        f"city100-iphonex, image-only critic (seed 0, {args.steps} steps):\n"
        f"its surest held-out 32x32 patches (at most {SUREST_PER_SCENE} per scene), 2x nearest;\n"
        f"captions: scene, top-left corner, the critic's logit towards the true class"
    )
    args.png.parent.mkdir(parents=True, exist_ok=True)
    surest = explained[BASELINE]["image-only"][0].surest
    args.png.write_bytes(surest_png(surest, names=names, title=title, detail_gain=DETAIL_GAIN))
    print(f"wrote {args.png}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    record = {
        "rows": {n: {m: [r.to_dict() for r in runs] for m, runs in modes.items()} for n, modes in results.items()},
        "explained": {
            n: {m: [e.to_dict() for e in runs] for m, runs in modes.items()} for n, modes in explained.items()
        },
        "measured": measured,
        "steps": args.steps,
        "seconds": round(time.perf_counter() - started, 1),
    }
    args.json.write_text(json.dumps(record, indent=2, allow_nan=False) + "\n")
    print(f"{time.perf_counter() - started:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
