"""Why the diagnosis names "add tone" before "refit vignetting" on the foreign webcam's vignetting scenario (issue 42).

On the webcam base fit that ``bench/bench_foreign_diagnosis.py`` caches (``OUT/fits/webcam-64x128``) and the
vignetting scenario's diagnosis pairs (24 of 128², split by scene as ``diagnose`` splits them, seed 0), three
measurements:

- **families**: the held-out gap and its families for the profile, the two changes as the diagnosis makes them
  (``add tone``, ``refit vignetting``), the refitted vignetting with the network's output curve refitted through the
  chain on the calibration frames (:mod:`camdegrade.fitting.network.chain_tone`, as the fit judges a
  position-dependent stage), the scenario's own added falloff (``1 − 0.45 r²`` in linear light) applied to the clean
  images before the network (where the camera has it), and the control's profile;
- **bands**: the simulation's tone residual minus the captures' (green, 8-bit levels) in 16 bins of clean value,
  in three rings of the frame (r relative, 1 at the corners), for ``refit vignetting`` and ``add tone``;
- **noise bins**: the held-out flat-pixel noise std per channel and bin of clean value (levels; ``None``: not
  measured) of the captures and of the profile and the two changes, with the bins the gap weighs (its scale);
- **flat**: the noise std of a flat field (green, 24² at the frame's centre, where neither vignetting acts) of the
  webcam camera and of the profile, by clean value: the profile's noise-by-level curve.

Run from the repo root::

    PYTHONPATH=src:tests OMP_NUM_THREADS=1 .venv/bin/python experiments/webcam_vignetting_cause.py --out /tmp/fd
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

from foreign_bench import DIAGNOSIS_SEED, OTHER_PHOTOS, make_pairs, to_tensor

from camdegrade import load_profile
from camdegrade.diagnose.attribution.changes import KINDS
from camdegrade.diagnose.attribution.search import Round, Search
from camdegrade.diagnose.heldout import Baseline, HeldOut
from camdegrade.effects import Vignetting
from camdegrade.effects.base import evenly_spaced
from camdegrade.fitting.network import chain_tone
from camdegrade.measures import StatisticSet, family_gaps
from camdegrade.pairs.pairset import PairSet
from camdegrade.profile import CameraProfile
from foreign_cameras import SCENARIOS

FAMILIES = ("spatial", "intensity", "noise", "color", "blocks")


def held_out(scenario: str) -> tuple[list, HeldOut]:
    made = make_pairs(SCENARIOS["webcam"][scenario].camera(), 24, 128, DIAGNOSIS_SEED, OTHER_PHOTOS)
    calibration, held = PairSet.load(made).split(0.5, 0)
    return calibration.unit_pairs(), HeldOut.build(held.unit_pairs(), 0, "held-out")


def row(label: str, held: HeldOut, stats: StatisticSet) -> None:
    families = family_gaps(held.real, stats, scale=held.scale)
    print(f"| {label} | {held.gap(stats):.2f} | " + " | ".join(f"{families[name]:.2f}" for name in FAMILIES) + " |")


def retoned(profile: CameraProfile, pairs: list) -> CameraProfile:
    """``profile`` with its network's output curve refitted through its deterministic stages on 12 frames."""
    inputs = chain_tone.curve_inputs(profile.network, evenly_spaced(pairs, 12))
    stages = list(profile.without_randomness().effects)
    knots = chain_tone.refit_output_curve(profile.network.curve[1], inputs, stages)
    return CameraProfile(chain_tone.with_output_curve(profile.network, knots), list(profile.effects))


def families(profile: CameraProfile) -> dict[str, CameraProfile]:
    calibration, held = held_out("vignetting")
    baseline = Baseline.measure(held, profile)
    search = Search(profile, calibration, held, baseline, 0)
    round_ = Round(search, profile, baseline.stats, baseline.gap, [], lambda line: None)
    index = next(i for i, stage in enumerate(profile.effects) if stage.name == "vignetting")
    tone, _, _ = KINDS["add"].make(round_, "tone")
    refit, stage, _ = KINDS["refit"].make(round_, index)
    print(f"refit vignetting: {stage.extra_repr()}; the profile's: {profile.effects[index].extra_repr()}")
    print("| profile | gap | " + " | ".join(FAMILIES) + " |\n|---|" + "---:|" * (len(FAMILIES) + 1))
    row("as fitted", held, baseline.stats)
    for label, changed in (("add tone", tone), ("refit vignetting", refit)):
        row(label, held, held.statistics(changed)[0])
    row("refit vignetting, output curve refitted", held, held.statistics(retoned(refit, calibration))[0])
    falloff = Vignetting(-0.45, 0.0)
    before = [falloff(clean[None])[0] for clean in held.cleans]
    sims = profile.simulate(before, held.seed, stream=held.stream)
    row("the added falloff on the clean image", held, StatisticSet.measure(sims, held.cleans, held.masks))
    _, control = held_out("control")
    row("control: as fitted", control, Baseline.measure(control, profile).stats)
    noise_bins(held, {"as fitted": profile, "add tone": tone, "refit vignetting": refit})
    return {"add tone": tone, "refit vignetting": refit}


def noise_bins(held: HeldOut, changed: dict[str, CameraProfile]) -> None:
    def rounded(values: torch.Tensor) -> list[list[float | None]]:
        return [[None if v != v else round(float(v), 2) for v in channel] for channel in values.reshape(3, -1)]

    print("noise std per channel (R, G, B) and bin of clean value:")
    print("  captures", rounded(held.real.values()["noise"]))
    for label, profile in changed.items():
        print(f"  {label}", rounded(held.statistics(profile)[0].values()["noise"]))
    print("  scale", rounded(held.scale["noise"]))


def bands(changed: dict[str, CameraProfile]) -> None:
    _, held = held_out("vignetting")
    rings = ((0.0, 0.5), (0.5, 0.8), (0.8, 2.0))
    real = [_tone_by_bin(held.reals, held.cleans, ring) for ring in rings]
    for label, profile in changed.items():
        sims = profile.simulate(held.cleans, 0, deterministic=True)
        for ring, captured in zip(rings, real, strict=True):
            residual = _tone_by_bin(sims, held.cleans, ring) - captured
            print(f"{label}, r in [{ring[0]}, {ring[1]}): sim − real", [round(float(v), 1) for v in residual])


def _tone_by_bin(images: list, cleans: list, ring: tuple[float, float]) -> np.ndarray:
    total, count = np.zeros(16), np.zeros(16)
    for image, clean in zip(images, cleans, strict=True):
        height, width = clean.shape[-2:]
        y, x = np.meshgrid(np.linspace(-1, 1, height), np.linspace(-1, 1, width), indexing="ij")
        inside = (np.sqrt((x**2 + y**2) / 2) >= ring[0]) & (np.sqrt((x**2 + y**2) / 2) < ring[1])
        green, reference = image[1].double().numpy()[inside], clean[1].double().numpy()[inside]
        bins = np.clip((reference * 16).astype(int), 0, 15)
        np.add.at(total, bins, (green - reference) * 255)
        np.add.at(count, bins, 1)
    return total / np.maximum(count, 1)


def flat(profile: CameraProfile) -> None:
    camera = SCENARIOS["webcam"]["control"].camera()
    centre = (slice(52, 76), slice(52, 76))
    print("| clean | camera std | profile std |\n|---:|---:|---:|")
    for value in (0.1, 0.2, 0.35, 0.5, 0.65, 0.8, 0.9):
        field = np.full((128, 128, 3), round(value * 255), np.uint8)
        captured = to_tensor(camera(field, seed=(7, 0)))[1][centre].double()
        simulated = profile.simulate([to_tensor(field)], 0)[0][1][centre].double() * 255
        print(f"| {value:.2f} | {float(captured.std()):.2f} | {float(simulated.std()):.2f} |")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=Path("/tmp/foreign"))
    args = parser.parse_args()
    torch.set_num_threads(1)
    profile = load_profile(args.out / "fits" / "webcam-64x128.safetensors")
    bands(families(profile))
    flat(profile)
    return 0


if __name__ == "__main__":
    sys.exit(main())
