"""Validation of the sim-to-real diagnosis on cameras whose difference from the profile is known.

A camera holds all nine effects at moderate strength. Missing-effect scenarios withhold one effect from the profile
(plus a motion-blur variant, another parametric form of blur); the other scenarios go the other way: a profile whose
noise is twice too strong, one with banding the camera lacks, white noise where the camera's is correlated, a
vignetting stage the camera lacks, and a network whose last layer imprints a checkerboard (the camera has the clean
network, then only noise and tone: optics after a network would blur its artefacts away). A "nothing different"
control checks for false alarms. Calibration and held-out pairs have different content (different scikit-image
photos, differently seeded generated textures and flat walls). Each scenario reports the expected and the accepted
change, the held-out gap before and after, the noise floor, the fraction of the gap closed, the critic's accuracy
before and after, and the parameters.

Run from the repo root::

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_diagnose.py            # 100 held-out pairs of 128² (docs table)
    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_diagnose.py --quick    # fewer, smaller pairs
    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_diagnose.py --timing   # the CLI on 100 pairs of 256²

Writes ``out/bench/diagnose.json``.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from markdown_tables import markdown_table
from torch import Tensor

from camdegrade import DomainShiftNet, load_profile
from camdegrade.diagnose import diagnose
from camdegrade.effects import EFFECTS, Effect
from camdegrade.profile import CameraProfile

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
Specs = list[tuple[str, dict[str, Any]]]
#: A stage of a camera with structured (processed) noise: correlated over neighbours and across channels, no banding.
_CORRELATED_NOISE = (
    "noise",
    {
        "levels": [[0.006, 0.01, 0.012, 0.012, 0.011, 0.01, 0.008, 0.006]] * 3,
        "across": [[-0.1, 0.563, 0.588, 0.563, -0.1]] * 3,
        "down": [[-0.1, 0.563, 0.588, 0.563, -0.1]] * 3,
        "mixing": [[1.0, 0.0, 0.0], [0.6, 0.8, 0.0], [0.5, 0.3, 0.81]],
        "linear": False,
    },
)


@dataclass(frozen=True)
class Scenario:
    """A real camera, the profile under test, the change the diagnosis should accept first, and whether the camera's
    and the profile's effect chains follow a network (clean, and with checkerboard artefacts in the profile)."""

    camera: Specs
    profile: Specs
    expected: tuple[str, str] | None
    network: bool = False
    #: The profile's own misfit, the change that fixes it (reported as its own finding, apart from ``expected``).
    misfit: tuple[str, str] | None = None


def _without(name: str, specs: Specs = CAMERA) -> Specs:
    return [(effect, kw) for effect, kw in specs if effect != name]


def _replaced(name: str, kwargs: dict[str, Any], specs: Specs = CAMERA) -> Specs:
    return [(effect, kwargs if effect == name else kw) for effect, kw in specs]


_NOISE = dict(CAMERA)["noise"]
#: After a network: sensor and ISP stages only. Optics after the network would blur its artefacts away, and the
#: fine-tune needs gradients through every stage (no codec).
_AFTER_NETWORK = [(name, kw) for name, kw in CAMERA if name in ("noise", "tone")]
#: An under-fitted profile of the camera: its blur stage half as wide (a fit that stopped early, or a network that
#: did not learn the lens): the profile's own misfit, beside which a withheld effect must still be found.
_UNDERFIT = _replaced("blur", {"sigma_x": 0.6})
_AFTER_NETWORK_COLOR = [(name, kw) for name, kw in CAMERA if name in ("noise", "color", "tone")]
SCENARIOS: dict[str, Scenario] = {
    **{name: Scenario(CAMERA, _without(name), ("add", name)) for name, _ in CAMERA},
    "blur-motion": Scenario(
        _replaced("blur", {"sigma_x": 0.6, "motion_length": 4.0, "motion_angle": 30.0}),
        _without("blur"),
        ("add", "blur"),
    ),
    "noise-2x": Scenario(CAMERA, _replaced("noise", {"a": 4 * _NOISE["a"], "b": 4 * _NOISE["b"]}), ("refit", "noise")),
    "banding-extra": Scenario(CAMERA, _replaced("noise", {**_NOISE, "row_sigma": 0.004}), ("refit", "noise")),
    "noise-correlated": Scenario(_replaced("noise", _CORRELATED_NOISE[1]), CAMERA, ("refit", "noise")),
    "vignetting-extra": Scenario(_without("vignetting"), CAMERA, ("remove", "vignetting")),
    "network-checkerboard": Scenario(_AFTER_NETWORK, _AFTER_NETWORK, ("network", "network"), network=True),
    "control": Scenario(CAMERA, CAMERA, None),
    "underfit-control": Scenario(CAMERA, _UNDERFIT, None, misfit=("refit", "blur")),
    "underfit-chromatic_aberration": Scenario(
        CAMERA, _without("chromatic_aberration", _UNDERFIT), ("add", "chromatic_aberration"), misfit=("refit", "blur")
    ),
    "underfit-color": Scenario(CAMERA, _without("color", _UNDERFIT), ("add", "color"), misfit=("refit", "blur")),
    "network-checkerboard-color": Scenario(
        _AFTER_NETWORK_COLOR, _AFTER_NETWORK, ("add", "color"), network=True, misfit=("network", "network")
    ),
}
#: The parameter compared for the parameter error of each effect (fitted vs true).
KEY_PARAM = {
    "misalignment": "dx",
    "distortion": "k1",
    "chromatic_aberration": "red",
    "vignetting": "k1",
    "blur": "sigma_x",
    "noise": "std",  # the std the stage adds to a flat mid-grey: the fitted stage is a table in sRGB, not a and b
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


def _walls(size: int, generator: torch.Generator) -> Tensor:
    """Generated flat content, like walls and sky: a 3×3 grid of uniform colours over a gentle gradient (well under a
    level per pixel), so that noise can be measured where the image is flat."""
    cells = F.interpolate(torch.rand(1, 3, 3, 3, generator=generator) * 0.9 + 0.05, size=(size, size), mode="nearest")
    ramp = torch.linspace(-0.04, 0.04, size)[None, :, None] * torch.rand(3, 1, 1, generator=generator)
    return (cells[0] + ramp).clamp(0.02, 0.98)


def content(count: int, size: int, photos: tuple[str, ...], seed: int) -> list[Tensor]:
    """``count`` clean images ``(3, size, size)``: random crops of ``photos`` (random scale, flips), and for one
    image in four each, a generated texture and generated flat walls."""
    generator = torch.Generator().manual_seed(seed)
    images = []
    for index in range(count):
        if index % 4 == 3:
            images.append(_texture(size, generator))
            continue
        if index % 4 == 1:
            images.append(_walls(size, generator))
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


def _chain(specs: Specs) -> list[Effect]:
    return [
        EFFECTS[name](**{k: torch.tensor(v) if isinstance(v, list) else v for k, v in kw.items()}) for name, kw in specs
    ]


#: A profile of the paper's network (the suite's network artefact is its transposed convolution's checkerboard).
PAPER_NETWORK_PROFILE = Path(__file__).resolve().parents[1] / "tests" / "fixtures" / "city100-iphonex-paper.safetensors"


@cache
def networks() -> tuple[DomainShiftNet, DomainShiftNet]:
    """A trained paper network (the built-in city100-iphonex's as shipped until 2026-11-27, kept as a test fixture)
    and a copy whose last layer imprints a 2×2 checkerboard (every weight of the last transposed convolution moved
    by ±0.004, about 7 levels on mid-grey): the network artefact of the suite."""
    clean = load_profile(PAPER_NETWORK_PROFILE).network
    assert clean is not None
    checker = copy.deepcopy(clean)
    pattern = torch.tensor([[1.0, -1.0], [-1.0, 1.0]])
    with torch.no_grad():
        checker.decode2.weight.add_(0.004 * pattern)
    return clean, checker


def scenario(
    name: str, calibration: int, held_out: int, size: int, seed: int = 0
) -> tuple[CameraProfile, list[tuple[Tensor, Tensor]], list[tuple[Tensor, Tensor]], dict[str, Any]]:
    """The profile under test, calibration and held-out REAL pairs (from the scenario's camera), and the truth."""
    spec = SCENARIOS[name]
    clean_network, checker_network = networks() if spec.network else (None, None)
    camera = CameraProfile(clean_network, _chain(spec.camera), name=name)
    profile = CameraProfile(checker_network, _chain(spec.profile), name=f"profile-{name}")
    pairs = []
    for part, (count, photos, offset) in enumerate(
        ((calibration, CALIBRATION_PHOTOS, 0), (held_out, HELD_OUT_PHOTOS, 1000))
    ):
        cleans = content(count, size, photos, seed * 7919 + offset + part)
        generator = torch.Generator().manual_seed(seed * 104729 + offset + 17)
        with torch.no_grad():
            pairs.append(
                [(clean, camera(clean[None], camera.make_params((1, *clean.shape), generator))[0]) for clean in cleans]
            )
    expected = spec.expected
    truth = dict(spec.camera).get(expected[1], {}) if expected and expected[0] == "add" else {}
    return profile, pairs[0], pairs[1], {"expected": expected, "truth": truth}


def parameter_error(
    name: str, truth: dict[str, Any], params: dict[str, Any], fitted: Effect | None = None
) -> float | None:
    """Relative error of the key parameter (absolute for the colour matrix: max entry difference)."""
    key = KEY_PARAM.get(name)
    if key == "std":
        return abs(_added_std(fitted) / _added_std(EFFECTS[name](**truth)) - 1.0) if fitted is not None else None
    if key is None or key not in params:
        return None
    if name == "color":
        true = torch.tensor(truth.get("matrix", torch.eye(3).tolist())).flatten()
        return float((torch.tensor(params["matrix"]) - true).abs().max())
    true_value = float(truth.get(key, 0.0))
    fitted = params[key][0] if isinstance(params[key], list) else params[key]
    return abs(float(fitted) - true_value) / abs(true_value) if true_value else None


def _added_std(stage: Effect, grey: float = 0.5, side: int = 256) -> float:
    """The std (8-bit levels scale: unit values) a noise stage alone adds to a flat ``grey`` image, sampled."""
    flat = torch.full((1, 3, side, side), grey)
    with torch.no_grad():
        noisy = stage(flat, stage.make_params(flat.shape, torch.Generator().manual_seed(0)))
    return float((noisy - flat).std())


def _stage(profile: CameraProfile | None, name: str) -> Effect | None:
    return next((effect for effect in profile.effects if effect.name == name), None) if profile is not None else None


def run_scenario(
    name: str,
    calibration: int,
    held_out: int,
    size: int,
    seed: int = 0,
    log: Any = None,
    candidates: list[str] | None = None,
) -> dict[str, Any]:
    """Diagnose one scenario; ``candidates`` limits the effects that may be added (default: all)."""
    profile, cal, held, info = scenario(name, calibration, held_out, size, seed)
    started = time.perf_counter()
    report = diagnose(profile, cal, held_out=held, seed=seed, log=log, candidates=candidates)
    seconds = time.perf_counter() - started
    expected, misfit = info["expected"], SCENARIOS[name].misfit
    top = report.accepted[0] if report.accepted else None
    expected_label = " ".join(expected) if expected else None
    found = _findings(report)
    params = report.fitted_params.get(expected[1], {}) if expected else {}
    critic = report.critic
    return {
        "scenario": name,
        "expected": expected_label,
        "top1": top,
        "accepted": report.accepted,
        **found,
        "expected_misfit": " ".join(misfit) if misfit else None,
        "correct": _correct(found, expected_label, " ".join(misfit) if misfit else None),
        "gap_before": round(report.gap_before, 3),
        "gap_after": round(report.gap_after, 3),
        "noise_floor": round(report.noise_floor, 3),
        "fraction_closed": round(report.fraction_closed, 3),
        "parameter_error": (
            parameter_error(expected[1], info["truth"], params, _stage(report.profile, expected[1]))
            if expected and info["truth"]
            else None
        ),
        "critic_before": critic.get("before", {}).get("accuracy"),
        "critic_after": critic.get("after", {}).get("accuracy"),
        "params": params,
        "ranking": [(f"{c['kind']} {c['name']}", round(c["reduction"], 2)) for c in report.changes[:4]],
        "verdict": report.verdict,
        "seconds": round(seconds, 1),
    }


def _findings(report: Any) -> dict[str, Any]:
    """The report's two findings: the profile's own misfit (accepted fixes) and the missing effects (the first of
    the ranking made once the misfit is fixed, and the accepted ones)."""
    missing = report.missing
    return {
        "misfit": [f"{row['kind']} {row['name']}" for row in report.misfit],
        "missing_first": f"{missing[0]['kind']} {missing[0]['name']}" if missing else None,
        "missing_accepted": [f"{row['kind']} {row['name']}" for row in missing if row["accepted"]],
    }


def _correct(found: dict[str, Any], expected: str | None, misfit: str | None) -> bool:
    """The expected change is the first finding of its kind (a missing effect: first of the ranking and accepted;
    a change to the profile: the first misfit fix), the scenario's own misfit is reported as such, and nothing
    else is accepted as missing."""
    misfits = [label for label in (misfit, expected) if label is not None and not label.startswith("add ")]
    missing = [expected] if expected is not None and expected.startswith("add ") else []
    if found["misfit"] != misfits[: len(found["misfit"])] or len(found["misfit"]) < len(misfits):
        return False
    if missing and found["missing_first"] != missing[0]:
        return False
    return found["missing_accepted"] == missing


def summary_table(rows: list[dict[str, Any]]) -> str:
    columns = (
        "scenario", "expected", "misfit reported", "missing, first", "accepted", "gap before", "gap after", "floor",
        "closed", "critic before → after", "param error", "s",
    )  # fmt: skip
    lines = markdown_table(columns, map(_summary_cells, rows), numeric=(*columns[5:9], *columns[10:]))
    scenarios = [row for row in rows if row["expected"]]
    correct = [row for row in scenarios if row["correct"]]
    control = [row for row in rows if not row["expected"]]
    closed = [row["fraction_closed"] for row in correct]
    critic_rows = [row for row in scenarios if row["critic_before"] is not None and row["critic_before"] > 0.6]
    false_alarms = sum(len(row["accepted"]) - (1 if row["expected_misfit"] else 0) for row in control)
    lines.append("")
    lines.append(
        f"right findings: {sum(row['correct'] for row in rows)}/{len(rows)} scenarios, controls included; "
        f"false alarms in the controls: {false_alarms}; gap closed in correct scenarios: "
        f"min {min(closed, default=0):.0%}, median {sorted(closed)[len(closed) // 2] if closed else 0:.0%}; "
        f"critic falls in {sum(row['critic_after'] < row['critic_before'] for row in critic_rows)}/"
        f"{len(critic_rows)} scenarios where it starts above 0.6"
    )
    return "\n".join(lines)


def _summary_cells(row: dict[str, Any]) -> list[str]:
    error = row["parameter_error"]
    critic = f"{row['critic_before']:.2f} → {row['critic_after']:.2f}" if row["critic_before"] is not None else "–"
    return [
        row["scenario"], row["expected"] or "–", ", ".join(row["misfit"]) or "none", row["missing_first"] or "–",
        ", ".join(row["accepted"]) or "none", f"{row['gap_before']:.2f}", f"{row['gap_after']:.2f}",
        f"{row['noise_floor']:.2f}", f"{row['fraction_closed']:.0%}", critic, "–" if error is None else f"{error:.2f}",
        f"{row['seconds']:.0f}",
    ]  # fmt: skip


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
        "accepted": report.get("accepted"),
        "critic_seconds": {label: critic.get("seconds") for label, critic in report.get("critic", {}).items()},
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
