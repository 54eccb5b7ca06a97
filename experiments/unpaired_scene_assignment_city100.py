"""How much of the City100 unpaired fit's held-out quality is the assignment of scenes to its two sets (issue 43).

Issue 43 judges the unpaired fit on one split: clean images of scenes 001–035, captures of 036–055, checked on the
16 held-out pairs (056–070, 098). This script fits the same default unpaired profile on other assignments of the
same 55 scenes (``k ≥ 1``: ``random.Random(k)`` shuffles 001–055, the first 35 give their clean images, the other
20 their captures; ``0`` is the issue's split) and checks each on the same held-out pairs: bands, flat noise, PSNR
(:func:`camdegrade.measures.fidelity.measure_fidelity`, seed 0, 8-bit as stored). Beside each row, the *content
bias* of its assignment: the fit's own spectrum statistic
(:func:`camdegrade.fitting.unpaired.steps.spectrum.mean_spectrum`) of the clean frames of the capture scenes less
that of the clean scenes, read on the Nikon frames of both, which the fit never sees: what an unpaired fit reads as
the camera's detail when it is the scenes'. Run from the repo root (each fit about 5 minutes on one core)::

    OMP_NUM_THREADS=1 .venv/bin/python experiments/unpaired_scene_assignment_city100.py --assignments 0 1 2 3 4 \
        [--profiles DIR] [--critic-seeds 4] [--show K ...] [--json PATH] [--png PATH]

``--critic-seeds N`` adds each row's image-only critic on the held-out pairs (2·N critics, each trained on half the
scenes and scored on the other: :func:`camdegrade.measures.critic.repeated_critic_test`) and the paired built-in's.

``--profiles DIR`` keeps each fitted profile there as ``assignment{k}.safetensors`` and reuses one found there.
The PNG: clean | capture | the simulation of each assignment of ``--show`` (default: the first four measured) | the
paired built-in, of 062 and 098: the flattest window at 1:1, and the most textured (062's text, 098's roof) at 2×
nearest-neighbour.
"""

from __future__ import annotations

import json
import random
from pathlib import Path

import torch
from fidelity_report import band_cell, band_heading, best_window, labelled_grid, number, real_pairs_parser, save_png
from fit_city100_unpaired import CAPTURED_SCENES, CLEAN_SCENES, DEFAULT_DATA, HELD_OUT, ROOT, _stored, city100, fit
from PIL import Image
from torch import Tensor

from camdegrade import load_profile
from camdegrade._support.pixels import as_unit, unit_to_bytes
from camdegrade.fitting.unpaired.steps.spectrum import (
    SPECTRUM_SIDE,
    band_centres,
    centre_crop,
    log_spectrum,
    mean_spectrum,
)
from camdegrade.functional.analysis.images import flat_mask, gradient_energy
from camdegrade.measures.critic import repeated_critic_test
from camdegrade.measures.fidelity import band_power, measure_fidelity

FITTING_SCENES = CLEAN_SCENES + CAPTURED_SCENES
SHOWN, TILE = ("062", "098"), 192


def assignment(k: int) -> tuple[list[str], list[str]]:
    """(clean scenes, capture scenes) of assignment ``k``: the issue's split for 0, else a seeded shuffle."""
    if k == 0:
        return list(CLEAN_SCENES), list(CAPTURED_SCENES)
    order = list(FITTING_SCENES)
    random.Random(k).shuffle(order)
    return sorted(order[: len(CLEAN_SCENES)]), sorted(order[len(CLEAN_SCENES) :])


def content_bias(scenes: dict[str, tuple[Tensor, Tensor]], clean: list[str], captured: list[str]) -> list[float]:
    """The fit's spectrum statistic of the capture scenes' clean frames less the clean scenes' (log2, per band)."""
    frames = {name: [as_unit(scenes[scene][0]) for scene in group] for name, group in (("a", clean), ("b", captured))}
    return [round(v, 3) for v in (mean_spectrum(frames["b"]) - mean_spectrum(frames["a"])).tolist()]


def assignment_precision(scenes: dict[str, tuple[Tensor, Tensor]]) -> dict[str, list[float]]:
    """How precisely 35 clean scenes against 20 others can say anything per band, whatever the fit: the spread over
    the 55 fitting scenes' clean frames of their log2 band power (the held-out bands' measure) and of the fit's own
    statistic, and the standard error that spread gives a difference of the two sets' means."""
    frames = [as_unit(scenes[scene][0]) for scene in FITTING_SCENES]
    powers = torch.stack([band_power(frame)[0] for frame in frames]).log2()
    spectra = torch.stack([log_spectrum(centre_crop(frame, SPECTRUM_SIDE)) for frame in frames])
    scale = (1 / len(CLEAN_SCENES) + 1 / len(CAPTURED_SCENES)) ** 0.5
    return {
        "band_std": [round(v, 3) for v in powers.std(0).tolist()],
        "band_standard_error": [round(v * scale, 3) for v in powers.std(0).tolist()],
        "statistic_std": [round(v, 3) for v in spectra.std(0).tolist()],
        "statistic_standard_error": [round(v * scale, 3) for v in spectra.std(0).tolist()],
    }


def profile_for(scenes, k: int, folder: Path | None):
    """The unpaired profile of assignment ``k``: loaded from ``folder`` where it is there, else fitted (and kept)."""
    path = folder / f"assignment{k}.safetensors" if folder else None
    if path is not None and path.is_file():
        return load_profile(path), None
    clean, captured = assignment(k)
    profile, seconds = fit(scenes, progress=False, captured=captured, clean=clean)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        profile.save(path)
    return profile, seconds


def held_out_quality(scenes, profile, critic_seeds: int) -> dict:
    """The held-out pairs' fidelity of ``profile`` (seed 0, 8-bit as stored) and, with ``critic_seeds``, its image-only
    critic."""
    cleans = [as_unit(scenes[scene][0]) for scene in HELD_OUT]
    reals = [as_unit(scenes[scene][1]) for scene in HELD_OUT]
    sims = _stored(profile.simulate(cleans, 0))
    report = measure_fidelity(sims, reals, cleans).to_dict(digits=3)
    if critic_seeds:
        critic = repeated_critic_test((cleans, reals, sims), HELD_OUT, critic_seeds, image_only=True)
        report["critic_image_only"] = critic.to_dict()
    return report


def row(scenes, k: int, profile, seconds: float | None, critic_seeds: int = 0) -> dict:
    clean, captured = assignment(k)
    tone = profile.fitted.get("effects", {}).get("color_tone", {})
    return {
        "assignment": k,
        "clean": clean,
        "captured": captured,
        "fit_seconds": None if seconds is None else round(seconds, 1),
        "stages": [effect.name for effect in profile.effects],
        "colour_gains": tone.get("gains"),
        "tone_change": tone.get("tone_change"),
        "content_bias": content_bias(scenes, clean, captured),
        "held_out": held_out_quality(scenes, profile, critic_seeds),
    }


def side_by_side(scenes, profiles: dict[str, object], path: Path) -> None:
    """Clean | capture | each profile's simulation of :data:`SHOWN`: the flattest window at 1:1 and the most textured
    at 2× nearest-neighbour."""
    rows = []
    for scene in SHOWN:
        clean, real = scenes[scene]
        unit = as_unit(clean)
        images = [clean, real]
        images += [unit_to_bytes(p.simulate([unit], HELD_OUT.index(scene))[0]) for p in profiles.values()]
        for kind, score, side in (
            ("flat 1:1", flat_mask(unit), TILE),
            ("texture 2x", gradient_energy(unit), TILE // 2),
        ):
            top, left = best_window(score, side)
            crops = [image[:, top : top + side, left : left + side].permute(1, 2, 0).numpy() for image in images]
            tiles = [Image.fromarray(c).resize((TILE, TILE), Image.NEAREST) for c in crops]
            rows.append((f"{scene} {kind}", tiles))
    save_png(labelled_grid(("clean", "capture", *profiles), rows, TILE), path)


def critic_cell(report: dict) -> str:
    critic = report.get("critic_image_only")
    return "not measured" if critic is None else f"{critic['accuracy']:.3f} ± {critic['std']:.2f}"


def format_table(table: list[dict]) -> str:
    centres = " / ".join(f"{c:.2f}" for c in band_centres()[-3:].tolist())
    lines = [
        f"| assignment | stages | {band_heading()} | flat-noise ratio | PSNR dB | critic image-only | content bias at "
        f"{centres} c/px |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in table:
        held = r["held_out"]
        bias = " / ".join(number(v, sign=True) for v in r["content_bias"][-3:])
        lines.append(
            f"| {r['assignment']} | {', '.join(r['stages'])} | {band_cell(held['bands'])} | "
            f"{number(held['noise_ratio'])} | {held['psnr']:.2f} | {critic_cell(held)} | {bias} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = real_pairs_parser(__doc__, DEFAULT_DATA)
    parser.add_argument("--assignments", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--profiles", type=Path, default=None, help="keep and reuse the fitted profiles here")
    parser.add_argument("--show", type=int, nargs="+", default=None, help="assignments drawn in the PNG")
    parser.add_argument("--critic-seeds", type=int, default=0, help="image-only critics: 2 per seed (0: none)")
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "results" / "unpaired_scene_assignment.json")
    parser.add_argument("--png", type=Path, default=ROOT / "docs" / "unpaired_scene_assignment.png")
    args = parser.parse_args(argv)
    if not (args.data / "pairs.csv").is_file():
        parser.error(f"no pairs.csv in {args.data}; pass --data with the real-pairs folder")
    if args.critic_seeds < 0:
        parser.error(f"--critic-seeds must be 0 or more, got {args.critic_seeds}")
    if any(k < 0 for k in args.assignments):
        parser.error(f"--assignments must be 0 or more, got {args.assignments}")
    shown = args.show if args.show is not None else args.assignments[:4]
    if not set(shown) <= set(args.assignments):
        parser.error(f"--show must name assignments among --assignments {args.assignments}, got {shown}")
    torch.manual_seed(0)
    scenes = city100(args.data)
    table, profiles = [], {}
    for k in args.assignments:
        profile, seconds = profile_for(scenes, k, args.profiles)
        table.append(row(scenes, k, profile, seconds, args.critic_seeds))
        if k in shown:
            profiles[f"assignment {k}"] = profile
        print(format_table(table[-1:]).splitlines()[-1], flush=True)
    profiles["paired built-in"] = load_profile("city100-iphonex")
    print(format_table(table))
    built_in = held_out_quality(scenes, profiles["paired built-in"], args.critic_seeds)
    print(f"paired built-in: bands {built_in['bands']}, critic image-only {critic_cell(built_in)}")
    precision = assignment_precision(scenes)
    print(
        f"scene spread, held-out bands' measure: std {precision['band_std']}, 35 vs 20 scenes' standard error "
        f"{precision['band_standard_error']}; the fit's statistic: {precision['statistic_standard_error']}"
    )
    side_by_side(scenes, profiles, args.png)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(
        json.dumps({"precision": precision, "built_in": built_in, "rows": table}, indent=1, allow_nan=False) + "\n"
    )
    print(f"wrote {args.json} and {args.png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
