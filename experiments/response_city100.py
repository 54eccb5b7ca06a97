"""What the frequency-response stage does on City100 iPhone X, and why its gains on the 4-pixel lattice are capped.

The built-in ``city100-iphonex`` without its last stage (network, blur, sharpen, denoise) is the base. A
:class:`~camdegrade.effects.FrequencyResponse` is fitted between the base's sampled 8-bit output and the captures on
every other scene of 001–055 (28 frames, fitting scenes only), with the lattice cap (the default) and without it,
and each is applied to the 16 held-out scenes (056–070, 098, whole frames, seed = scene index): grid ratio, the
five bands, flat noise, PSNR; with ``--critic-seeds N`` also 2N critics per row (the image-only one is what a model
trained on the simulation sees). The shipped built-in is the last row. Run from the repo root (about 2 minutes;
``--critic-seeds 4`` about 8)::

    OMP_NUM_THREADS=2 .venv/bin/python experiments/response_city100.py [--critic-seeds 4]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from torch import Tensor

from camdegrade import CameraDegrade, CameraProfile, load_profile
from camdegrade._support.pixels import as_unit
from camdegrade.effects import FrequencyResponse
from camdegrade.fitting import discover_pairs, filter_pairs, load_pair
from camdegrade.measures.critic import repeated_critic_test
from camdegrade.measures.fidelity import measure_fidelity

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real-pairs"
HELD_OUT = {f"{n:03d}" for n in range(56, 71)} | {"098"}


def sampled(profile: CameraProfile, cleans: list[Tensor]) -> list[Tensor]:
    """Each clean uint8 image through the profile as training sees it (seed = index, 8-bit), as float."""
    return [as_unit(CameraDegrade(profile, seed=index)(clean)) for index, clean in enumerate(cleans)]


def row(name: str, sims: list[Tensor], reals: list[Tensor], cleans: list[Tensor], scenes, seeds: int) -> dict:
    fidelity = measure_fidelity(sims, reals, cleans).to_dict(digits=3)
    out = {"row": name, **{key: fidelity[key] for key in ("psnr", "grid_ratio", "bands", "noise_ratio")}}
    for key, image_only in (("critic_image_only", True), ("critic_paired", False)):
        if seeds:
            result = repeated_critic_test((cleans, reals, sims), scenes, seeds, image_only=image_only)
            out[key] = f"{result.accuracy:.3f} ± {result.std:.3f} [{result.low:.2f}–{result.high:.2f}]"
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--critic-seeds", type=int, default=0, help="critics per row: 2 per seed (0: none)")
    args = parser.parse_args()
    shipped = load_profile("city100-iphonex")
    base = shipped.with_chain([e for e in shipped.effects if not isinstance(e, FrequencyResponse)])
    pairs = filter_pairs(discover_pairs(args.data / "pairs.csv").pairs, subset="city100_iPhoneX")
    fitting = [pair for pair in pairs if pair.scene <= "055"][::2]
    held = [pair for pair in pairs if pair.scene in HELD_OUT]
    fit_cleans, fit_reals = zip(*(load_pair(pair) for pair in fitting), strict=True)
    fit_sims = sampled(base, list(fit_cleans))
    fit_reals = [as_unit(real) for real in fit_reals]
    held_cleans, held_reals = zip(*(load_pair(pair) for pair in held), strict=True)
    cleans, reals = [as_unit(clean) for clean in held_cleans], [as_unit(real) for real in held_reals]
    scenes = [pair.scene for pair in held]
    profiles = {"base (no response)": base}
    for label, lattice in (("response, lattice not capped", False), ("response, lattice capped", True)):
        profiles[label] = base.with_effects(FrequencyResponse.fit(fit_sims, fit_reals, lattice=lattice))
    profiles["shipped city100-iphonex"] = shipped
    print(f"{len(fitting)} fitting frames, {len(held)} held-out frames")
    for name, profile in profiles.items():
        sims = sampled(profile, list(held_cleans))
        print(json.dumps(row(name, sims, reals, cleans, scenes, args.critic_seeds), ensure_ascii=False), flush=True)


if __name__ == "__main__":
    main()
