"""Issue 43's PolyU case: an unpaired profile of real DSLR noise that paints red speckle, with and without a
learned texture stage.

Captures: the noisy shots of the first 10 PolyU scenes (sorted by file name, one crop per scene), centre crops of
128² saved as JPEG at quality 85 (so the fit reads the quantisation tables); clean images: the mean images of the
next 10 scenes, centre crops of 128² (lossless). :func:`~camdegrade.fitting.unpaired.fit_unpaired` fits the profile,
:func:`~camdegrade.fitting.two_sample.gate.fit_learned_stage` adds a learned stage where the held-out halves keep it,
and the stage trained on all images without the gate is measured too. For each: a flat grey input (0.45, 0.55) →
the output's std and mean per channel (8-bit levels), the captures' own flat-pixel noise beside it, and the set
statistics of the clean images' simulation against the captures (band log2 differences, flat-noise ratio)::

    OMP_NUM_THREADS=2 .venv/bin/python experiments/two_sample_polyu.py [--steps 1200]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from camdegrade import CameraProfile
from camdegrade._support.pixels import as_unit
from camdegrade.fitting import Pair, discover_pairs, filter_pairs, load_pair
from camdegrade.fitting.two_sample.gate import StageTraining, fit_learned_stage, set_statistics
from camdegrade.fitting.two_sample.train import TwoSampleOptions, fit_two_sample
from camdegrade.fitting.unpaired import fit_unpaired
from camdegrade.fitting.unpaired.steps.noise import flat_sums

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DATA = ROOT.parent / "shared" / "data" / "real-pairs"
SIDE, COUNT, QUALITY = 128, 10, 85
GREYS = (0.45, 0.55)


def crop(image: torch.Tensor) -> torch.Tensor:
    height, width = image.shape[-2:]
    top, left = (height - SIDE) // 2, (width - SIDE) // 2
    return image[:, top : top + SIDE, left : left + SIDE]


def write_sets(data: Path, folder: Path) -> tuple[Path, Path]:
    """The captures (JPEG q85) and the clean images (PNG) of the case, written to ``folder``."""
    pairs = sorted(
        filter_pairs(discover_pairs(data / "pairs.csv").pairs, subset="polyu_real_noise"), key=lambda p: p.name
    )
    by_scene: dict[str, Pair] = {}
    for pair in pairs:  # one crop per scene: the scene is the stem without its crop number
        by_scene.setdefault(pair.scene.rsplit("_", 1)[0], pair)
    chosen = list(by_scene.values())[: 2 * COUNT]
    captured, clean = folder / "captured", folder / "clean"
    captured.mkdir(parents=True)
    clean.mkdir(parents=True)
    for index, pair in enumerate(chosen):
        mean, real = load_pair(pair)
        array = crop(real if index < COUNT else mean).permute(1, 2, 0).numpy()
        if index < COUNT:
            Image.fromarray(array).save(captured / f"{index:02d}.jpg", quality=QUALITY)
        else:
            Image.fromarray(array).save(clean / f"{index:02d}.png")
    return captured, clean


def read(folder: Path) -> list[torch.Tensor]:
    return [
        as_unit(torch.from_numpy(np.array(Image.open(p).convert("RGB"))).permute(2, 0, 1))
        for p in sorted(folder.iterdir())
    ]


def flat_response(profile: CameraProfile) -> dict[str, dict[str, list[float]]]:
    """Per grey level: the output's std and mean per channel (levels) on a flat input of 128² (seed 0)."""
    out = {}
    for grey in GREYS:
        image = torch.full((1, 3, SIDE, SIDE), grey)
        with torch.no_grad():
            result = profile(image, profile.make_params(image.shape, torch.Generator().manual_seed(0)))[0] * 255
        out[f"{grey:g}"] = {
            "std": [round(float(v), 2) for v in result.std((1, 2))],
            "mean": [round(float(v), 1) for v in result.mean((1, 2))],
        }
    return out


def measured(profile: CameraProfile, cleans: list, captures: list) -> dict:
    sims = []
    with torch.no_grad():
        for index, clean in enumerate(cleans):
            params = profile.make_params((1, *clean.shape), torch.Generator().manual_seed(index))
            sims.append(profile(clean[None], params)[0].mul(255).round().div(255))
    return {"flat_input": flat_response(profile), **set_statistics(sims, captures)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--steps", type=int, default=1200)
    parser.add_argument("--options", default="{}", help="TwoSampleOptions fields as JSON")
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "results" / "two_sample_polyu.json")
    args = parser.parse_args(argv)
    options = TwoSampleOptions(**{"patch": 48, **json.loads(args.options)})
    with tempfile.TemporaryDirectory() as temporary:
        captured, clean = write_sets(args.data, Path(temporary))
        profile = fit_unpaired(captured, clean, name="polyu-unpaired")
        captures, cleans = read(captured), read(clean)
    own = flat_sums(captures).pooled_std()  # levels
    record = {"captures_own_flat_std_levels": round(own, 2), "recorded_check": profile.quality["unpaired_fidelity"]}
    started = time.perf_counter()
    gated, evidence = fit_learned_stage(profile, cleans, captures, StageTraining(steps=args.steps, options=options))
    record["gate"] = {
        "kept": evidence["kept"],
        "judgements": evidence["judgements"],
        "seconds": round(time.perf_counter() - started, 1),
    }
    ungated, _ = fit_two_sample(profile, cleans, captures, steps=args.steps, options=options)
    record["rows"] = {
        "unpaired (today)": measured(profile, cleans, captures),
        "unpaired + learned stage (no gate)": measured(profile.with_effects(ungated), cleans, captures),
    }
    if gated is not None:
        record["rows"]["unpaired + learned stage (gated)"] = measured(profile.with_effects(gated), cleans, captures)
    print(json.dumps(record, indent=1))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(record, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
