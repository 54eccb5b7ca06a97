"""Validation of the sim-to-real diagnosis on virtual cameras whose withheld effect is known.

For every effect of the registry (plus a motion-blur variant, another parametric form of blur) a virtual camera
holds all nine effects at moderate strength; the "profile" holds the same effects minus the withheld one (an
effects-only profile: fitting a network per scenario would take hours on a CPU). A "nothing withheld" control
checks for false alarms. Calibration and held-out pairs have different content (different scikit-image photos
and differently seeded generated textures). Each scenario reports the top-1 effect, the added effects, the
held-out gap before/after, the noise floor, the fraction of the gap closed and the fitted parameters.

Run from the repo root::

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_diagnose.py            # 100 held-out pairs of 128² (docs table)
    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_diagnose.py --quick    # fewer, smaller pairs
    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_diagnose.py --timing   # the CLI on 100 pairs of 256²

Writes ``out/bench/diagnose.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from functools import cache
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade.diagnose import diagnose
from camdegrade.effects import EFFECTS
from camdegrade.profile import CameraProfile
from camdegrade.sim import VirtualCamera

#: The full virtual camera, physical order, moderate strengths at 128².
CAMERA: list[tuple[str, dict[str, Any]]] = [
    ("misalignment", {"dx": 0.8, "dy": -0.6}),
    ("distortion", {"k1": 0.06}),
    ("chromatic_aberration", {"red": 0.008, "blue": -0.007}),
    ("vignetting", {"k1": -0.3}),
    ("blur", {"sigma_x": 1.2}),
    ("noise", {"a": 0.002, "b": 1e-5}),
    ("color", {"matrix": [[1.08, 0.04, -0.02], [0.02, 1.0, 0.0], [-0.02, 0.06, 0.88]]}),
    ("tone", {"gamma": 1.12, "black": 0.03, "white": 0.95}),
    ("jpeg", {"quality": 60}),
]
#: Scenario name → (withheld effect, replacement settings of that effect in the real camera, or None).
SCENARIOS: dict[str, tuple[str | None, dict[str, Any] | None]] = {
    **{name: (name, None) for name, _ in CAMERA},
    "blur-motion": ("blur", {"sigma_x": 0.6, "motion_length": 4.0, "motion_angle": 30.0}),
    "control": (None, None),
}
#: The parameter compared for the parameter error of each effect (fitted vs true).
KEY_PARAM = {
    "misalignment": "dx",
    "distortion": "k1",
    "chromatic_aberration": "red",
    "vignetting": "k1",
    "blur": "sigma_x",
    "noise": "a",
    "color": "matrix",
    "tone": "gamma",
    "jpeg": "quality",
}
CALIBRATION_PHOTOS = ("astronaut", "coffee", "immunohistochemistry", "brick", "grass")
HELD_OUT_PHOTOS = ("chelsea", "rocket", "hubble_deep_field", "retina", "camera", "gravel", "colorwheel")


@cache
def _photo(name: str) -> Tensor:
    import skimage.data

    array = getattr(skimage.data, name)()
    image = torch.from_numpy(array).float().div(255.0)
    if image.ndim == 2:  # tint grey textures so that every channel varies
        image = torch.stack([image * 0.95 + 0.03, image, image * 0.85 + 0.1], -1)
    return image[..., :3].permute(2, 0, 1).contiguous()


def _texture(size: int, generator: torch.Generator) -> Tensor:
    """Generated content: a smooth colour field, flat shapes at many intensities, and fine stripes."""
    coarse = torch.rand(3, 4, 4, generator=generator)
    image = F.interpolate(coarse[None], size=(size, size), mode="bicubic", align_corners=False)[0]
    yy, xx = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    for _ in range(6):
        cy, cx, radius = (torch.rand(3, generator=generator) * torch.tensor([size, size, size / 4])).tolist()
        colour = torch.rand(3, 1, 1, generator=generator)
        inside = ((yy - cy) ** 2 + (xx - cx) ** 2) < (radius + 4) ** 2
        image = torch.where(inside, colour, image)
    top, left = (torch.randint(0, size // 2, (2,), generator=generator)).tolist()
    period = float(torch.rand((), generator=generator) * 6 + 3)
    stripes = 0.5 + 0.4 * torch.sin(2 * math.pi * (xx + 0.5 * yy) / period)
    block = (slice(top, top + size // 3), slice(left, left + size // 3))
    image[:, block[0], block[1]] = stripes[block].expand(3, -1, -1) * torch.rand(3, 1, 1, generator=generator)
    return image.clamp(0.02, 0.98)


def content(count: int, size: int, photos: tuple[str, ...], seed: int) -> list[Tensor]:
    """``count`` clean images ``(3, size, size)``: random crops of ``photos`` (random scale, flips) and, for one
    image in four, a generated texture."""
    generator = torch.Generator().manual_seed(seed)
    images = []
    for index in range(count):
        if index % 4 == 3:
            images.append(_texture(size, generator))
            continue
        photo = _photo(photos[int(torch.randint(0, len(photos), (1,), generator=generator))])
        scale = float(torch.empty(()).uniform_(0.5, 1.0, generator=generator)) * min(photo.shape[-2:]) / size
        side = max(size, int(size * scale))
        top = int(torch.randint(0, photo.shape[-2] - side + 1, (1,), generator=generator))
        left = int(torch.randint(0, photo.shape[-1] - side + 1, (1,), generator=generator))
        crop = photo[:, top : top + side, left : left + side]
        crop = F.interpolate(crop[None], size=(size, size), mode="area")[0]
        if bool(torch.rand((), generator=generator) < 0.5):
            crop = crop.flip(-1)
        images.append(crop.clamp(0, 1))
    return images


def scenario(
    name: str, calibration: int, held_out: int, size: int, seed: int = 0
) -> tuple[CameraProfile, list[tuple[Tensor, Tensor]], list[tuple[Tensor, Tensor]], dict[str, Any]]:
    """The profile (camera minus the withheld effect), calibration and held-out REAL pairs, and the truth."""
    withheld, replacement = SCENARIOS[name]
    real_specs = [
        (effect, dict(replacement) if effect == withheld and replacement else dict(kw)) for effect, kw in CAMERA
    ]
    camera = VirtualCamera([EFFECTS[effect](**kw) for effect, kw in real_specs], scale=1.0, name=name)
    profile = CameraProfile(
        None, [EFFECTS[effect](**kw) for effect, kw in CAMERA if effect != withheld], name=f"without-{withheld}"
    )
    pairs = []
    for part, (count, photos, offset) in enumerate(
        ((calibration, CALIBRATION_PHOTOS, 0), (held_out, HELD_OUT_PHOTOS, 1000))
    ):
        cleans = content(count, size, photos, seed * 7919 + offset + part)
        generator = torch.Generator().manual_seed(seed * 104729 + offset + 17)
        with torch.no_grad():
            pairs.append([(clean, camera(clean[None], generator=generator)[0]) for clean in cleans])
    truth = dict(real_specs).get(withheld, {}) if withheld else {}
    return profile, pairs[0], pairs[1], {"withheld": withheld, "truth": truth}


def parameter_error(name: str, truth: dict[str, Any], params: dict[str, Any]) -> float | None:
    """Relative error of the key parameter (absolute for the colour matrix: max entry difference)."""
    key = KEY_PARAM.get(name)
    if key is None or key not in params:
        return None
    if name == "color":
        true = torch.tensor(truth.get("matrix", torch.eye(3).tolist())).flatten()
        return float((torch.tensor(params["matrix"]) - true).abs().max())
    true_value = float(truth.get(key, 0.0))
    fitted = params[key][0] if isinstance(params[key], list) else params[key]
    return abs(float(fitted) - true_value) / abs(true_value) if true_value else None


def run_scenario(
    name: str, calibration: int, held_out: int, size: int, seed: int = 0, log: Any = None
) -> dict[str, Any]:
    profile, cal, held, info = scenario(name, calibration, held_out, size, seed)
    started = time.perf_counter()
    report = diagnose(profile, cal, held_out=held, seed=seed, log=log)
    seconds = time.perf_counter() - started
    withheld = info["withheld"]
    top1 = report.effects[0]["name"] if report.added else None
    params = report.fitted_params.get(withheld, {}) if withheld else {}
    return {
        "scenario": name,
        "withheld": withheld,
        "top1": top1,
        "added": report.added,
        "correct": top1 == withheld,
        "gap_before": round(report.gap_before, 3),
        "gap_after": round(report.gap_after, 3),
        "noise_floor": round(report.noise_floor, 3),
        "fraction_closed": round(report.fraction_closed, 3),
        "parameter_error": parameter_error(withheld, info["truth"], params) if withheld else None,
        "params": params,
        "ranking": [(e["name"], round(e["reduction"], 2)) for e in report.effects[:4]],
        "seconds": round(seconds, 1),
    }


def summary_table(rows: list[dict[str, Any]]) -> str:
    lines = [
        "| scenario | withheld | top-1 | added | gap before | gap after | floor | closed | param error | s |",
        "|---|---|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for row in rows:
        error = row["parameter_error"]
        lines.append(
            f"| {row['scenario']} | {row['withheld'] or '–'} | {row['top1'] or 'none'} "
            f"| {', '.join(row['added']) or 'none'} | {row['gap_before']:.2f} | {row['gap_after']:.2f} "
            f"| {row['noise_floor']:.2f} | {row['fraction_closed']:.0%} "
            f"| {'–' if error is None else f'{error:.2f}'} | {row['seconds']:.0f} |"
        )
    scenarios = [row for row in rows if row["withheld"]]
    correct = [row for row in scenarios if row["correct"]]
    control = [row for row in rows if not row["withheld"]]
    closed = [row["fraction_closed"] for row in correct]
    lines.append("")
    lines.append(
        f"top-1 correct: {len(correct)}/{len(scenarios)}; false alarms in the control: "
        f"{sum(len(row['added']) for row in control)}; gap closed in correct scenarios: "
        f"min {min(closed, default=0):.0%}, median {sorted(closed)[len(closed) // 2] if closed else 0:.0%}"
    )
    return "\n".join(lines)


def timing(pairs: int = 100, size: int = 256) -> dict[str, Any]:
    """Wall time of ``camdegrade diagnose`` on ``pairs`` pairs of ``size``² written as PNG (the CLI path)."""
    from camdegrade.io import write_image

    profile, cal, held, _ = scenario("blur", pairs // 2, pairs - pairs // 2, size)
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder)
        for index, (clean, captured) in enumerate([*cal, *held]):
            for side, image in (("clean", clean), ("captured", captured)):
                write_image(image.mul(255).round().to(torch.uint8), root / "pairs" / side / f"{index:03d}.png")
        profile.save(root / "profile.safetensors")
        command = [
            sys.executable,
            "-m",
            "camdegrade",
            "diagnose",
            str(root / "profile.safetensors"),
            str(root / "pairs"),
            "--json",
            str(root / "report.json"),
            "--html",
            str(root / "report.html"),
        ]
        started = time.perf_counter()
        result = subprocess.run(command, capture_output=True, text=True, check=False)
        seconds = time.perf_counter() - started
        report = json.loads((root / "report.json").read_text()) if result.returncode == 0 else {}
    return {
        "pairs": pairs,
        "size": size,
        "seconds": round(seconds, 1),
        "returncode": result.returncode,
        "added": report.get("added"),
        "stderr": result.stderr[-400:],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="40 held-out pairs of 96², a few scenarios")
    parser.add_argument("--timing", action="store_true", help="only time the CLI on 100 pairs of 256²")
    parser.add_argument("--scenarios", nargs="*", default=None, help=f"subset of {list(SCENARIOS)}")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--verbose", action="store_true", help="print the diagnosis progress")
    parser.add_argument("--out", type=Path, default=Path("out/bench/diagnose.json"))
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    if args.timing:
        result = timing()
        print(json.dumps(result, indent=2))
        return 0 if result["returncode"] == 0 else 1
    names = args.scenarios or list(SCENARIOS)
    calibration, held_out, size = (40, 40, 96) if args.quick else (100, 100, 128)
    rows = []
    for name in names:
        row = run_scenario(name, calibration, held_out, size, args.seed, log=print if args.verbose else None)
        print(json.dumps({k: v for k, v in row.items() if k != "params"}), flush=True)
        rows.append(row)
    print(summary_table(rows))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps({"calibration": calibration, "held_out": held_out, "size": size, "rows": rows}, indent=2) + "\n"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
