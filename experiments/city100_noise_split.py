"""Fit a profile's noise stage on the training scenes only, or on those and the validation scenes, and compare both
on the validation scenes: does the held-out evidence of a fit (``camdegrade.fitting.steps.noise_evidence``) cost
anything?

The profile is the paper-network built-in ``city100-iphonex`` (as shipped until 2026-11-27) without its noise stage
(its network, blur and tone curve); the noise is fitted by ``fit_noise_stage`` on City100 iPhone X scenes 001–047,
or 001–055, and the profile with it is sampled on the validation scenes 048–055 and rounded to 8 bits. Printed: the
flat-pixel noise of the captures and of the profile without noise, then per fit the flat-noise and banding ratios
(simulation / capture), the fitted row banding and the seconds the fit took. Run from the repo root::

    OMP_NUM_THREADS=1 .venv/bin/python experiments/city100_noise_split.py [--data DIR]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from fit_city100 import DEFAULT_DATA, city100_iphone_pairs, load

from camdegrade import load_profile
from camdegrade._support.pixels import as_unit
from camdegrade.fitting.in_chain import CALIBRATION_PAIRS, fit_noise_stage
from camdegrade.fitting.steps.noise_evidence import as_stored
from camdegrade.functional.analysis.images import flat_mask
from camdegrade.functional.analysis.noise import measure_set
from camdegrade.measures.fidelity import noise_ratios

#: The built-in city100-iphonex as shipped until 2026-11-27 (the paper's network + blur, noise, tone), which this
#: evidence is about; the built-in has been a local-affine fit since.
PAPER_BUILT_IN = Path(__file__).resolve().parents[1] / "tests" / "fixtures" / "city100-iphonex-paper.safetensors"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    args = parser.parse_args()
    pairs = city100_iphone_pairs(args.data)
    train = [(as_unit(c), as_unit(r)) for c, r in load(pairs, lambda scene: scene <= "047")]
    val = [(as_unit(c), as_unit(r)) for c, r in load(pairs, lambda scene: "048" <= scene <= "055")]
    full = load_profile(PAPER_BUILT_IN)
    profile = full.with_chain([effect for effect in full.effects if effect.name != "noise"])
    cleans, reals = [c for c, _ in val], [r for _, r in val]
    masks = [flat_mask(clean) for clean in cleans]
    real = measure_set(reals, cleans, masks)
    base = measure_set(as_stored(profile.simulate(cleans, 0, deterministic=True), True), cleans, masks)
    print(
        f"validation: {real.pixels} flat pixels, capture noise {real.pooled_std():.3f} levels, profile without noise "
        f"{base.pooled_std():.3f} (ratio {noise_ratios(base, real)[0]:.3f}, banding {noise_ratios(base, real)[1]:.3f})"
    )
    for label, fit_pairs in (("training scenes", train), ("training + validation scenes", val + train)):
        started = time.perf_counter()
        noise = fit_noise_stage(
            profile, [c for c, _ in fit_pairs], [r for _, r in fit_pairs], calibration_pairs=CALIBRATION_PAIRS
        )
        seconds = time.perf_counter() - started
        sampled = as_stored(profile.with_effects(noise).simulate(cleans, 0, stream="quality"), True)
        noise_ratio, banding_ratio = noise_ratios(measure_set(sampled, cleans, masks), real)
        rows = [round(value * 255, 3) for value in noise.row_sigma.tolist()]
        print(
            f"fitted on {len(fit_pairs)} {label}: noise ratio {noise_ratio:.3f}, banding ratio {banding_ratio:.3f}, "
            f"row banding {rows} levels, fit {seconds:.0f} s"
        )


if __name__ == "__main__":
    main()
