"""Visual and statistical evidence that the built-in ``city100-iphonex`` looks like the real iPhone X captures.

For the 16 held-out City100 scenes (056–070, 098; never used in any fit) it prints the noise statistics where the
clean image is flat in absolute terms (gradient magnitude < 1.5 levels at Gaussian σ = 2, eroded by 8 px), pooled
over all scenes: the std of the image minus its 17×17 local mean (8-bit levels), the std of the per-row and
per-column means of that residual, the correlation with the neighbour 1 and 2 pixels away, and how many pixels and
rows these rest on. Rows: the real capture, the built-in profile sampled as training sees it (``CameraDegrade``,
``seed=0``), the profile as it shipped before the flat-region noise fit (a test fixture), the profile without its
noise stage, and the clean image.

It also writes ``docs/city100_noise.png``: for three scenes, a flat crop and a textured crop at 1:1, side by side
as clean | real | simulated (built-in) | simulated (before); and it asks the learned critic of the diagnosis
(``camdegrade.measures.critic.core``) how well it tells the real captures from each profile's samples: trained on 8 of
the scenes, scored on the other 8, each scene cut to its 256² window with the most flat pixels. Run from the repo
root::

    OMP_NUM_THREADS=2 .venv/bin/python experiments/city100_noise_evidence.py [--data DIR] [--png PATH] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch.nn.functional as F
from PIL import Image, ImageDraw
from torch import Tensor

from camdegrade import CameraDegrade, CameraProfile, load_profile
from camdegrade._support.pixels import as_unit
from camdegrade.fitting import discover_pairs, filter_pairs, load_pair
from camdegrade.functional.analysis.images import flat_mask, flattest_window, gradient_energy
from camdegrade.functional.analysis.noise import NoiseSums
from camdegrade.measures.critic import critic_test

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DATA = ROOT.parent / "shared" / "data" / "real-pairs"
BEFORE = ROOT / "tests" / "fixtures" / "city100-iphonex-2026-11-23.safetensors"
HELD_OUT = sorted({f"{n:03d}" for n in range(56, 71)} | {"098"})
SHOWN = ("060", "062", "098")
CROP = 128


def held_out_pairs(data: Path) -> list[tuple[str, Tensor, Tensor]]:
    """``(scene, clean, real)`` uint8 for the held-out City100 iPhone X scenes."""
    pairs = {p.scene: p for p in filter_pairs(discover_pairs(data / "pairs.csv").pairs, subset="city100_iPhoneX")}
    return [(scene, *load_pair(pairs[scene])) for scene in HELD_OUT]


def renders(profiles: dict[str, CameraProfile], clean: Tensor) -> dict[str, Tensor]:
    """Each profile applied to ``clean`` as training sees it: a seeded ``CameraDegrade``, uint8 in and out."""
    return {name: CameraDegrade(profile, seed=0)(clean) for name, profile in profiles.items()}


def statistics(data: Path) -> tuple[dict[str, NoiseSums], dict[str, dict[str, Tensor]]]:
    current = load_profile("city100-iphonex")
    profiles = {"built-in": current, "before": load_profile(BEFORE), "without noise": current.without_randomness()}
    sums = {name: NoiseSums.zeros() for name in ("real", *profiles, "clean")}
    shown: dict[str, dict[str, Tensor]] = {}
    for scene, clean, real in held_out_pairs(data):
        unit_clean = as_unit(clean)
        mask = flat_mask(unit_clean)
        images = {"real": real, **renders(profiles, clean), "clean": clean}
        for name, image in images.items():
            sums[name] = sums[name] + NoiseSums.measure(as_unit(image), unit_clean, mask)
        if scene in SHOWN:
            shown[scene] = {"clean": clean, "real": real, "built-in": images["built-in"], "before": images["before"]}
    return sums, shown


def table(sums: dict[str, NoiseSums]) -> list[dict]:
    real = sums["real"]
    rows = []
    for name, measured in sums.items():
        lines = measured.line_variance()[0].mean(1).sqrt()  # rows, columns: RMS over channels
        correlation = measured.correlation().mean(-1)  # (axis, lag)
        rows.append(
            {
                "image": name,
                "flat_pixels": measured.pixels,
                "rows": int(measured.line_count()[0]),
                "noise_std": round(measured.pooled_std(), 3),
                "noise_ratio": round(measured.pooled_std() / real.pooled_std(), 2),
                "row_std": round(float(lines[0]), 3),
                "row_ratio": round(float(lines[0] / real.line_variance()[0].mean(1).sqrt()[0]), 2),
                "column_std": round(float(lines[1]), 3),
                "correlation_h1_h2_v1_v2": [round(float(v), 3) for v in correlation.flatten()],
            }
        )
    return rows


def format_table(rows: list[dict]) -> str:
    header = (
        f"{'image':<14} {'flat px':>10} {'rows':>6} {'noise std':>10} {'ratio':>6} {'row std':>8} {'ratio':>6} "
        f"{'col std':>8}  correlation h1 h2 v1 v2"
    )
    lines = [header, "-" * len(header)]
    for row in rows:
        corr = " ".join(f"{v:.2f}" for v in row["correlation_h1_h2_v1_v2"])
        lines.append(
            f"{row['image']:<14} {row['flat_pixels']:>10,} {row['rows']:>6} {row['noise_std']:>10.3f} "
            f"{row['noise_ratio']:>6.2f} {row['row_std']:>8.3f} {row['row_ratio']:>6.2f} {row['column_std']:>8.3f}  "
            f"{corr}"
        )
    return "\n".join(lines)


def _window(score: Tensor) -> tuple[int, int]:
    """Top-left corner of the ``CROP``² window with the highest mean ``score``."""
    pooled = F.avg_pool2d(score[None, None].float(), CROP, stride=16)[0, 0]
    top, left = divmod(int(pooled.argmax()), pooled.shape[1])
    return top * 16, left * 16


def evidence_png(shown: dict[str, dict[str, Tensor]], path: Path) -> None:
    """Rows of 1:1 crops (flat, then textured, per scene): clean | real | built-in | before, with labels."""
    columns = ("clean", "real", "built-in", "before")
    label_height, gap = 16, 4
    tiles = []
    for scene, images in shown.items():
        unit_clean = as_unit(images["clean"])
        flat = _window(flat_mask(unit_clean).float())
        textured = _window(gradient_energy(unit_clean))
        for kind, (top, left) in (("flat", flat), ("textured", textured)):
            tiles.append((f"{scene} {kind}", [images[c][:, top : top + CROP, left : left + CROP] for c in columns]))
    width = len(columns) * (CROP + gap) + 90
    height = label_height + len(tiles) * (CROP + gap)
    canvas = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(canvas)
    for index, name in enumerate(columns):
        draw.text((90 + index * (CROP + gap), 2), name, fill="black")
    for row, (label, crops) in enumerate(tiles):
        y = label_height + row * (CROP + gap)
        draw.text((4, y + CROP // 2 - 6), label, fill="black")
        for index, crop in enumerate(crops):
            canvas.paste(Image.fromarray(crop.permute(1, 2, 0).numpy()), (90 + index * (CROP + gap), y))
    path.parent.mkdir(parents=True, exist_ok=True)
    canvas.save(path)


def critic_table(data: Path, seed: int = 0) -> list[dict]:
    """The critic's held-out accuracy for each profile's samples against the real captures (0.5: indistinguishable)."""
    current = load_profile("city100-iphonex")
    profiles = {"built-in": current, "without noise": current.without_randomness(), "before": load_profile(BEFORE)}
    crops = [flattest_crop(clean, real) for _, clean, real in held_out_pairs(data)]
    cleans = [as_unit(clean) for clean, _ in crops]
    reals = [as_unit(real) for _, real in crops]
    rows = []
    for name, profile in profiles.items():
        sims = [as_unit(CameraDegrade(profile, seed=seed + index)(clean)) for index, (clean, _) in enumerate(crops)]
        fit, check = slice(0, None, 2), slice(1, None, 2)
        result = critic_test((cleans[fit], reals[fit], sims[fit]), (cleans[check], reals[check], sims[check]), seed)
        rows.append({"profile": name, **result.to_dict()})
    return rows


def flattest_crop(clean: Tensor, real: Tensor, side: int = 256) -> tuple[Tensor, Tensor]:
    """Both images cut to the ``side``² window (on the 8-pixel grid) with the most flat pixels."""
    window, _ = flattest_window(as_unit(clean), side)
    return clean[(slice(None), *window)], real[(slice(None), *window)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--png", type=Path, default=ROOT / "docs" / "city100_noise.png")
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "results" / "city100_noise.json")
    args = parser.parse_args(argv)
    if not (args.data / "pairs.csv").is_file():
        parser.error(f"no pairs.csv in {args.data}; pass --data with the real-pairs folder")
    sums, shown = statistics(args.data)
    rows = table(sums)
    print(format_table(rows))
    evidence_png(shown, args.png)
    print(f"wrote {args.png}")
    critics = critic_table(args.data)
    for row in critics:
        print(
            f"critic, {row['profile']:<14} accuracy {row['accuracy']:.2f} [{row['low']:.2f}–{row['high']:.2f}] "
            f"on {row['patches']} held-out patches (flat {row['by_texture']['flat']['accuracy']})"
        )
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"statistics": rows, "critic": critics}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
