"""Does the iPhone X sharpen? The sharpen stage fitted on top of the paper-network built-in ``city100-iphonex`` as
shipped until 2026-11-27 (``tests/fixtures/city100-iphonex-paper.safetensors``; issue 23).

Fits :class:`~camdegrade.effects.Sharpen` on City100 iPhone X scenes 001–055 with the built-in profile's
deterministic output (``simulate(profile, cleans, seed=0, deterministic=True)``, the conditional mean a diagnosis
fits candidates against) as the source and the real capture as the target. Fits: as the diagnosis fits a candidate
(``Sharpen.fit_within_budget``: 24 evenly spaced pairs, 4 crops of 64² each, σ ≤ 4 px), the same per channel, with
σ ≤ 1.5 px (a halo-scale sharpening only) and with σ ≤ 8 px; with ``--all-pairs`` also on all 55 pairs (8 crops
each). On the 16 held-out scenes (056–070, 098; never used in any fit), whole frames, it prints
:func:`~camdegrade.measures.measure_fidelity` of the built-in and of the built-in + each fitted sharpen (the stage
goes after ``tone``, last in the chain), deterministic and sampled (``simulate(..., seed=0)``, noise included, as
training sees it): the five band log2 power ratios sim/real, the paired PSNR, the flat-pixel noise ratio and the
4×4 grid ratio.

It writes a PNG of real | built-in | built-in + sharpen (sampled, the diagnosis-budget luma fit) for scenes 098
and 062: the flattest 128² window at 1:1 and the most textured 64² window at 2× nearest-neighbour. Run from the
repo root::

    OMP_NUM_THREADS=2 PYTHONPATH=src python experiments/sharpen_city100.py [--data DIR] [--png PATH]
"""

from __future__ import annotations

import time
from pathlib import Path

import torch
from fidelity_report import band_cell, band_heading, best_window, labelled_grid, number, real_pairs_parser, save_png
from PIL import Image
from torch import Tensor

from camdegrade import CameraProfile, load_profile
from camdegrade._support.pixels import as_unit, unit_to_bytes
from camdegrade.effects import Sharpen
from camdegrade.effects.base import evenly_spaced
from camdegrade.fitting import discover_pairs, filter_pairs, load_pair
from camdegrade.functional.analysis.images import flattest_window, gradient_energy
from camdegrade.measures import measure_fidelity

ROOT = Path(__file__).resolve().parents[1]
#: The built-in city100-iphonex as shipped until 2026-11-27 (the paper's network + blur, noise, tone), which this
#: evidence is about; the built-in has been a local-affine fit since.
PAPER_BUILT_IN = Path(__file__).resolve().parents[1] / "tests" / "fixtures" / "city100-iphonex-paper.safetensors"
DEFAULT_DATA = ROOT.parent / "shared" / "data" / "real-pairs"
FIT = [f"{n:03d}" for n in range(1, 56)]
HELD_OUT = sorted({f"{n:03d}" for n in range(56, 71)} | {"098"})
SHOWN = ("098", "062")
FLAT, TEXTURED = 128, 64


def load(data: Path, scenes: list[str]) -> tuple[list[Tensor], list[Tensor]]:
    """``(cleans, reals)`` float in [0, 1] for the City100 iPhone X ``scenes``."""
    pairs = {p.scene: p for p in filter_pairs(discover_pairs(data / "pairs.csv").pairs, subset="city100_iPhoneX")}
    loaded = [load_pair(pairs[scene]) for scene in scenes]
    return [as_unit(clean) for clean, _ in loaded], [as_unit(real) for _, real in loaded]


def fits(profile: CameraProfile, data: Path, all_pairs: bool) -> dict[str, Sharpen]:
    """The sharpen stages fitted on scenes 001–055 against the profile's deterministic output."""
    cleans, reals = load(data, FIT)
    sources = profile.simulate(cleans, seed=0, deterministic=True)
    chosen, targets = evenly_spaced(sources, Sharpen.fit_budget), evenly_spaced(reals, Sharpen.fit_budget)
    options = Sharpen.fit_options(chosen)
    variants = {
        "budget, luma": lambda: Sharpen.fit_within_budget(sources, reals),
        "budget, per channel": lambda: Sharpen.fit(chosen, targets, **{**options, "luma": False}),
        "budget, luma, σ ≤ 1.5": lambda: Sharpen.fit(chosen, targets, **{**options, "max_sigma": 1.5}),
        "budget, luma, σ ≤ 8": lambda: Sharpen.fit(chosen, targets, **{**options, "max_sigma": 8.0}),
    }
    if all_pairs:
        variants["55 pairs, luma"] = lambda: Sharpen.fit(sources, reals, **{**options, "crops_per_image": 8})
    fitted = {}
    for label, fit in variants.items():
        start = time.perf_counter()
        fitted[label] = fit()
        print(f"fit ({label}): {fitted[label].extra_repr()} in {time.perf_counter() - start:.1f} s")
    return fitted


def held_out_rows(profile: CameraProfile, fitted: dict[str, Sharpen], data: Path) -> tuple[list[dict], dict]:
    """measure_fidelity of every row on the held-out scenes, and the sampled images of the scenes shown.

    A sharpen stage goes last in this chain (after ``tone``) and draws nothing, so the built-in + sharpen is the
    stage applied to the built-in's output with the same draws (checked on one frame)."""
    cleans, reals = load(data, HELD_OUT)
    first = next(iter(fitted.values()))
    check = profile.with_effects(first).simulate(cleans[:1], seed=0)[0]
    rows, shown = [], {scene: {"real": reals[HELD_OUT.index(scene)]} for scene in SHOWN}
    for mode, deterministic in (("deterministic", True), ("sampled", False)):
        built_in = profile.simulate(cleans, seed=0, deterministic=deterministic)
        if not deterministic:
            torch.testing.assert_close(first(built_in[0][None])[0], check, atol=1e-5, rtol=0)
        sims = {"built-in": built_in}
        with torch.no_grad():
            sims |= {f"+ sharpen ({k})": [e(image[None])[0] for image in built_in] for k, e in fitted.items()}
        for name, images in sims.items():
            rows.append({"mode": mode, "row": name, **measure_fidelity(images, reals, cleans).to_dict()})
            if not deterministic:
                for scene in SHOWN:
                    shown[scene][name] = images[HELD_OUT.index(scene)]
    return rows, shown


def format_table(rows: list[dict]) -> str:
    lines = [
        f"| mode | image | {band_heading()} | PSNR dB | noise ratio | grid ratio |",
        "|---|---|---|---|---|---|",
    ]
    for row in rows:
        cells = [row["mode"], row["row"], band_cell(row["bands"]), f"{row['psnr']:.2f}", number(row["noise_ratio"])]
        lines.append(f"| {' | '.join(cells)} | {number(row['grid_ratio'], 1)} |")
    return "\n".join(lines)


def evidence_png(shown: dict[str, dict[str, Tensor]], cleans: dict[str, Tensor], path: Path) -> None:
    """Per scene two rows (flat 1:1, textured 2×), columns real | built-in | built-in + sharpen."""
    columns = ("real", "built-in", "+ sharpen (budget, luma)")
    rows = []
    for scene, images in shown.items():
        (flat_rows, flat_cols), _ = flattest_window(cleans[scene], FLAT)
        top, left = best_window(gradient_energy(cleans[scene]), TEXTURED)
        windows = (
            ("flat 1:1", (flat_rows, flat_cols)),
            ("texture 2x", (slice(top, top + TEXTURED), slice(left, left + TEXTURED))),
        )
        for kind, (ys, xs) in windows:
            crops = [unit_to_bytes(images[name][:, ys, xs]).permute(1, 2, 0).numpy() for name in columns]
            rows.append((f"{scene} {kind}", [Image.fromarray(c).resize((FLAT, FLAT), Image.NEAREST) for c in crops]))
    save_png(labelled_grid(columns, rows, FLAT, label_width=110, label_drop=6), path)


def main(argv: list[str] | None = None) -> int:
    parser = real_pairs_parser(__doc__, DEFAULT_DATA)
    parser.add_argument("--png", type=Path, default=ROOT / "out" / "sharpen_city100.png")
    parser.add_argument("--all-pairs", action="store_true", help="also fit on all 55 pairs (8 crops each; slow)")
    args = parser.parse_args(argv)
    if not (args.data / "pairs.csv").is_file():
        parser.error(f"no pairs.csv in {args.data}; pass --data with the real-pairs folder")
    profile = load_profile(PAPER_BUILT_IN)
    fitted = fits(profile, args.data, args.all_pairs)
    rows, shown = held_out_rows(profile, fitted, args.data)
    print(format_table(rows))
    cleans, _ = load(args.data, list(SHOWN))
    evidence_png(shown, dict(zip(SHOWN, cleans, strict=True)), args.png)
    print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
