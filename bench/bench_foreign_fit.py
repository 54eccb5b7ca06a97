"""Default fits of the foreign cameras (issue 42): how close ``camdegrade fit``'s defaults get to cameras it did
not build.

Each camera of ``tests/foreign_cameras`` (numpy, scipy and PIL only) makes training pairs of 128² from one set of
photos plus walls and dead leaves; ``fit_profile(pairs)`` with the default recipe fits it (one thread; the profile is
kept in ``OUT/fits/`` and reused by ``bench_foreign_diagnosis.py``). On held-out pairs of other photos and seeds:

- the profile's PSNR, sampled (its random stages drawn, rounded to 8 bits) and deterministic (its conditional mean);
- a blur + colour-map chain fitted by least squares on the same training pairs (a Gaussian blur of the sRGB image,
  its σ on a grid, then a 3×3 matrix and an offset), the simple answer the fit must beat;
- the output codes each skips (codes between the darkest and brightest value that no pixel takes, pooled over
  channels and pairs): a tone table on 8-bit values skips codes, a float simulation does not.

Beside them, the fit's own fidelity record (``profile.quality['fidelity']``, on its validation split): the critics
(image-only, paired), the band log2 power ratios, the flat-noise and banding ratios, the 4-pixel grid ratio; the same
image-only critic (same seeds) trained and scored on the held-out pairs; whether the fit warned
(``profile.fitted['warnings']``).

Run from the repo root::

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_foreign_fit.py             # 8 cameras, 120 training pairs each
    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_foreign_fit.py --quick     # 2 cameras, 48 pairs
    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_foreign_fit.py --png docs/foreign_cameras.png  # capture | fit |
                                                                             # blur + colour map, 2x and 1:1

Writes ``OUT/fit/CAMERA.json`` per camera (``--table-only`` prints the table of those already written).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch
from foreign_bench import DEFAULT_OUT, Pairs, fitted_profile, held_out_pairs, stages_of, train_pairs
from PIL import Image, ImageDraw
from scipy import ndimage

from camdegrade import load_profile
from camdegrade.fitting.quality import FIT_CRITIC_SEEDS
from camdegrade.measures.critic import repeated_critic_test
from camdegrade.measures.metrics import psnr
from foreign_cameras import CAMERAS, camera

#: σ (pixels) tried for the baseline's Gaussian blur.
BLUR_SIGMAS = np.round(np.arange(0.0, 3.01, 0.1), 2)


def _unit(image: torch.Tensor) -> np.ndarray:
    """uint8 (3, H, W) tensor → float (H, W, 3) in [0, 1]."""
    return image.permute(1, 2, 0).numpy().astype(np.float64) / 255.0


def _blurred(image: np.ndarray, sigma: float) -> np.ndarray:
    return ndimage.gaussian_filter(image, (sigma, sigma, 0), mode="mirror") if sigma > 0 else image


def fit_blur_colour_map(pairs: Pairs) -> tuple[float, np.ndarray]:
    """The σ and the (4, 3) affine colour map (3×3 matrix and offset) minimising the training pairs' squared error,
    the map solved by least squares for each σ of :data:`BLUR_SIGMAS` (every second pixel of every pair)."""
    cleans = [_unit(clean) for clean, _ in pairs]
    targets = np.concatenate([_unit(captured)[::2, ::2].reshape(-1, 3) for _, captured in pairs])
    best = (np.inf, 0.0, np.zeros((4, 3)))
    for sigma in BLUR_SIGMAS:
        inputs = np.concatenate([_blurred(clean, sigma)[::2, ::2].reshape(-1, 3) for clean in cleans])
        design = np.concatenate([inputs, np.ones((len(inputs), 1))], axis=1)
        colour_map, *_ = np.linalg.lstsq(design, targets, rcond=None)
        error = float(((design @ colour_map - targets) ** 2).mean())
        if error < best[0]:
            best = (error, float(sigma), colour_map)
    return best[1], best[2]


def blur_colour_map(image: np.ndarray, sigma: float, colour_map: np.ndarray) -> torch.Tensor:
    """The baseline's output for one clean image (float (H, W, 3)), rounded to 8 bits, as a unit tensor (3, H, W)."""
    mapped = _blurred(image, sigma) @ colour_map[:3] + colour_map[3]
    rounded = np.round(np.clip(mapped, 0.0, 1.0) * 255.0) / 255.0
    return torch.from_numpy(rounded.transpose(2, 0, 1)).float()


def skipped_codes(images: list[torch.Tensor]) -> int:
    """Codes between the darkest and the brightest value that no pixel of ``images`` takes (uint8 or unit)."""
    codes = torch.cat(
        [(image.float() * (255.0 if image.dtype != torch.uint8 else 1.0)).round().flatten() for image in images]
    )
    used = torch.bincount(codes.long().clamp(0, 255), minlength=256) > 0
    low, high = int(codes.min()), int(codes.max())
    return int((~used[low : high + 1]).sum())


def _fidelity(profile: Any) -> dict[str, Any]:
    """The fit's own fidelity record, the critics reduced to their accuracies."""
    record = dict((profile.quality or {}).get("fidelity") or {})
    for key in ("critic_paired", "critic_image_only"):
        critic = record.get(key)
        record[key] = None if critic is None else critic.get("accuracy", critic.get("mean"))
    return record


def held_out_critic(cleans: list[torch.Tensor], reals: list[torch.Tensor], sampled: list[torch.Tensor]) -> float:
    """The image-only critic of the fit's fidelity record (same seeds) on the held-out pairs, each its own scene."""
    scenes = [f"held-out-{index}" for index in range(len(cleans))]
    result = repeated_critic_test((cleans, reals, sampled), scenes, FIT_CRITIC_SEEDS, image_only=True)
    return round(float(result.to_dict()["accuracy"]), 3)


def ungated_row(profile: Any, cleans: list[torch.Tensor], reals: list[torch.Tensor]) -> dict[str, float]:
    """Held-out image-only critic and PSNR (sampled, mean) of the profile with its learned stage, gate or not."""
    sampled = profile.simulate(cleans, 0, stream="foreign-held-out", eight_bit=True)
    mean = profile.simulate(cleans, 0, stream="foreign-held-out", deterministic=True, eight_bit=True)
    scores = [sum(psnr(i, r) for i, r in zip(images, reals, strict=True)) / len(reals) for images in (sampled, mean)]
    critic = held_out_critic(cleans, reals, sampled)
    return {"critic_held_out_image_only": critic, "psnr_sampled": round(scores[0], 2), "psnr_mean": round(scores[1], 2)}


def measure(name: str, args: argparse.Namespace) -> dict[str, Any]:
    """One camera's row: its default fit, held-out PSNRs, the baseline, skipped codes and the fit's own record."""
    log = (lambda line: print(f"[{name}] {line}", flush=True)) if args.verbose else None
    profile, record = fitted_profile(
        name, args.fit_pairs, args.size, args.out, log=log, learned_texture=args.learned_texture
    )
    held = held_out_pairs(camera(name), args.held_out, args.size)
    cleans = [clean.float().div(255.0) for clean, _ in held]
    reals = [captured.float().div(255.0) for _, captured in held]
    sampled = profile.simulate(cleans, 0, stream="foreign-held-out", eight_bit=True)
    mean = profile.simulate(cleans, 0, stream="foreign-held-out", deterministic=True, eight_bit=True)
    sigma, colour_map = fit_blur_colour_map(train_pairs(name, args.fit_pairs, args.size))
    baseline = [blur_colour_map(_unit(clean), sigma, colour_map) for clean, _ in held]
    fitted = profile.fitted or {}

    def mean_psnr(images: list[torch.Tensor]) -> float:
        return round(sum(psnr(image, real) for image, real in zip(images, reals, strict=True)) / len(reals), 2)

    extra = {"learned_texture": fitted.get("learned_texture")} if args.learned_texture else {}
    if record.get("ungated"):
        extra["ungated"] = ungated_row(load_profile(args.out / "fits" / record["ungated"]), cleans, reals)
    return {
        "camera": name,
        "chain": camera(name).describe(),
        "stages": stages_of(profile),
        "fit_seconds": record["seconds"],
        "fit_cpu_seconds": record.get("cpu_seconds"),
        "fit_pairs": args.fit_pairs,
        "held_out_pairs": args.held_out,
        "size": args.size,
        "psnr_sampled": mean_psnr(sampled),
        "psnr_mean": mean_psnr(mean),
        "psnr_identity": mean_psnr(cleans),
        "psnr_blur_colour_map": mean_psnr(baseline),
        "critic_held_out_image_only": held_out_critic(cleans, reals, sampled),
        "blur_sigma": sigma,
        "colour_map": np.round(colour_map, 6).tolist(),
        "skipped_codes": {"capture": skipped_codes([real for _, real in held]), "profile": skipped_codes(sampled)},
        "fidelity": _fidelity(profile),
        "fit_psnr": {key: value for key, value in (profile.quality or {}).items() if key.endswith("_psnr_db")},
        "resolution": fitted.get("resolution"),
        "warnings": fitted.get("warnings", []),
        "save_error": record.get("save_error"),
        **extra,
    }


def _number(value: float | None, digits: int = 2) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def table(rows: list[dict[str, Any]]) -> str:
    lines = [
        "| camera | stages kept | held-out PSNR sampled / mean / blur+colour map / clean (dB) | critic image-only "
        "/ paired | bands log2 sim/real | flat noise / banding ratio | grid ratio | skipped codes capture / sim "
        "| held-out critic image-only | fit warns | fit s |",
        "|---|---|---|---|---|---|---|---|---|---|---:|",
    ]
    for row in rows:
        fidelity = row["fidelity"]
        bands = " / ".join(_number(value) for value in fidelity.get("bands", []))
        lines.append(
            f"| {row['camera']} | {', '.join(row['stages'])} | {row['psnr_sampled']:.2f} / {row['psnr_mean']:.2f} / "
            f"{row['psnr_blur_colour_map']:.2f} (σ {row['blur_sigma']:.1f}) / {row['psnr_identity']:.2f} "
            f"| {_number(fidelity.get('critic_image_only'))} / {_number(fidelity.get('critic_paired'))} | {bands} "
            f"| {_number(fidelity.get('noise_ratio'))} / {_number(fidelity.get('banding_ratio'))} "
            f"| {_number(fidelity.get('grid_ratio'))} | {row['skipped_codes']['capture']} / "
            f"{row['skipped_codes']['profile']} | {_number(row.get('critic_held_out_image_only'))} "
            f"| {'yes' if row['warnings'] else 'no'} | {row['fit_seconds']:.0f} |"
        )
    return "\n".join(lines)


def _window(clean: np.ndarray, side: int, flattest: bool) -> tuple[tuple[int, int], float]:
    """Top-left of the ``side``² window (stride 8) with the least (``flattest``) or most gradient energy, and that
    energy."""
    luma = clean.astype(np.float64).mean(axis=-1)
    energy = np.hypot(*np.gradient(luma))
    scores = {
        (top, left): energy[top : top + side, left : left + side].sum()
        for top in range(0, luma.shape[0] - side + 1, 8)
        for left in range(0, luma.shape[1] - side + 1, 8)
    }
    corner = (min if flattest else max)(scores, key=scores.__getitem__)
    return corner, float(scores[corner])


def _tile(image: np.ndarray, corner: tuple[int, int], side: int, zoom: int) -> Image.Image:
    top, left = corner
    crop = Image.fromarray(image[top : top + side, left : left + side])
    return crop.resize((side * zoom, side * zoom), Image.Resampling.NEAREST)


def baseline_of(name: str, args: argparse.Namespace) -> tuple[float, np.ndarray]:
    """The camera's blur + colour-map baseline: read from its row (``OUT/fit/CAMERA.json``), else fitted."""
    path = args.out / "fit" / f"{name}.json"
    row = json.loads(path.read_text()) if path.is_file() else {}
    if "colour_map" in row:
        return row["blur_sigma"], np.asarray(row["colour_map"])
    return fit_blur_colour_map(train_pairs(name, args.fit_pairs, args.size))


def evidence_tiles(name: str, profile: Any, args: argparse.Namespace) -> list[Image.Image]:
    """On held-out pairs: capture | default-fit simulation | blur + colour-map baseline of the most textured 48²
    window of the photo crops at 2× nearest-neighbour, then of the flattest 96² window of the walls scenes at 1:1."""
    held = held_out_pairs(camera(name), 8, args.size)
    sigma, colour_map = baseline_of(name, args)
    side = min(96, args.size)
    tiles = []
    for indices, zoom, crop, flattest in (((0, 2, 4, 6), 2, side // 2, False), ((1, 5), 1, side, True)):
        windows = {index: _window(held[index][0].permute(1, 2, 0).numpy(), crop, flattest) for index in indices}
        index = (min if flattest else max)(windows, key=lambda i: windows[i][1])
        clean, captured = held[index]
        sim = profile.simulate([clean.float().div(255.0)], 0, stream="foreign-png", eight_bit=True)[0]
        base = blur_colour_map(_unit(clean), sigma, colour_map)
        trio = [captured, sim.mul(255).round().byte(), base.mul(255).round().byte()]
        tiles += [_tile(image.permute(1, 2, 0).numpy(), windows[index][0], crop, zoom) for image in trio]
    return tiles


def shown_profile(name: str, args: argparse.Namespace) -> Any:
    """The profile :func:`evidence_png` shows: the default fit, or with ``--learned-texture`` the fit with the stage
    its learned step trained, whether the gate kept it or not (``OUT/fits/...-ungated``)."""
    profile, record = fitted_profile(name, args.fit_pairs, args.size, args.out, None, args.learned_texture)
    return load_profile(args.out / "fits" / record["ungated"]) if record.get("ungated") else profile


def evidence_png(names: list[str], args: argparse.Namespace, path: Path) -> None:
    """The crops of :func:`evidence_tiles` of each camera's default fit (fitted, or loaded from ``OUT/fits/``;
    :func:`shown_profile`) in one PNG, a row per camera."""
    rows = [(name, evidence_tiles(name, shown_profile(name, args), args)) for name in names]
    _compose(rows, path, "fit+stage" if args.learned_texture else "default fit")


def _compose(rows: list[tuple[str, list[Image.Image]]], path: Path, fit: str) -> None:
    labels = [f"{kind} {zoom}" for zoom in ("2x", "1:1") for kind in ("capture", fit, "blur+map")]
    gap, head, side = 4, 14, rows[0][1][0].width
    canvas = Image.new("RGB", (6 * (side + gap) + 90, len(rows) * (side + gap) + head), "white")
    draw = ImageDraw.Draw(canvas)
    for column, label in enumerate(labels):
        draw.text((90 + column * (side + gap), 1), label, fill="black")
    for row, (name, images) in enumerate(rows):
        top = head + row * (side + gap)
        draw.text((2, top + side // 2), name, fill="black")
        for column, image in enumerate(images):
            canvas.paste(image, (90 + column * (side + gap), top))
    path.parent.mkdir(parents=True, exist_ok=True)
    canvas.save(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cameras", nargs="*", default=list(CAMERAS), choices=list(CAMERAS))
    parser.add_argument("--fit-pairs", type=int, default=120)
    parser.add_argument("--held-out", type=int, default=48)
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--quick", action="store_true", help="webcam and phone, 48 training and 16 held-out pairs")
    parser.add_argument("--png", type=Path, default=None, help="write the crops of --png-cameras' fits to this PNG")
    parser.add_argument("--png-cameras", nargs="*", default=list(CAMERAS))
    parser.add_argument("--table-only", action="store_true", help="print the table of the rows already written")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--verbose", action="store_true", help="print the fit's log")
    parser.add_argument(
        "--learned-texture",
        choices=("critic",),
        default=None,
        help="fit with the recipe option learned_texture (fit --learned-texture critic); profiles kept apart",
    )
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    if args.quick:
        args.cameras, args.fit_pairs, args.held_out = ["webcam", "phone"], 48, 16
    folder = args.out / "fit"
    if args.png is not None:
        evidence_png(args.png_cameras, args, args.png)
        return 0
    if not args.table_only:
        folder.mkdir(parents=True, exist_ok=True)
        for name in args.cameras:
            row = measure(name, args)
            (folder / f"{name}.json").write_text(json.dumps(row, indent=2) + "\n")
            print(json.dumps({k: row[k] for k in ("camera", "stages", "psnr_sampled", "psnr_blur_colour_map")}))
    order = list(CAMERAS)
    rows = sorted((json.loads(p.read_text()) for p in folder.glob("*.json")), key=lambda r: order.index(r["camera"]))
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
