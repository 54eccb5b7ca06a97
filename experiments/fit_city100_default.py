"""A default fit (``fit_profile`` with the fast recipe: ``arch="local_affine"``) of the City100 iPhone X, scored on
the 16 held-out scenes — the numbers issue 23's architecture step rests on.

Fits on the REAL pairs of scenes 001–055 (``fit_profile`` splits off 15 % of them by scene to validate), writes the
profile, and prints its ``quality`` (validation PSNR of the identity, the least-squares linear baseline, the network
and the sampled profile; fidelity numbers) and, on the held-out scenes 056–070 and 098 (never used in the fit), the
paired PSNR of the sampled profile and of its network alone, and :func:`~camdegrade.measures.measure_fidelity`.
The held-out numbers go into the profile's ``quality`` (the fit's own validation numbers under ``validation``),
with 8 critics (4 seeds, each trained on half the held-out scenes and scored on the other half, and back).
Compare it with the built-ins in one table with ``experiments/fidelity_city100.py --profile "default fit=OUT"``.
Run from the repo root::

    OMP_NUM_THREADS=2 .venv/bin/python experiments/fit_city100_default.py [--arch local_affine] [--out PATH] \
        [--upsample smooth] [--curves none] [--texture none] [--name NAME]

The built-in ``city100-iphonex`` is this fit with the defaults::

    OMP_NUM_THREADS=2 .venv/bin/python experiments/fit_city100_default.py --name city100-iphonex \
        --out src/camdegrade/profiles/city100-iphonex.safetensors
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from camdegrade import CameraDegrade
from camdegrade._support.pixels import as_unit
from camdegrade._support.recipes import CURVES, TEXTURES, UPSAMPLINGS
from camdegrade.fitting import FitConfig, PairSet, discover_pairs, filter_pairs, fit_profile, load_pair
from camdegrade.measures.critic import repeated_critic_test
from camdegrade.measures.fidelity import measure_fidelity
from camdegrade.measures.metrics import psnr

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DATA = ROOT.parent / "shared" / "data" / "real-pairs"
LAST_FITTED_SCENE = "055"
#: Critic seeds on the held-out scenes (8 critics, as ``experiments/fidelity_city100.py``).
CRITIC_SEEDS = 4
DESCRIPTION = "iPhone X at a distance vs. close-up (City100, real lens/distance blur, tone shift and ISP texture)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--arch", default="local_affine", choices=("local_affine", "paper"))
    parser.add_argument("--epochs", type=int, default=None, help="default: the fast recipe's")
    parser.add_argument("--upsample", default=None, choices=UPSAMPLINGS, help="default: the fast recipe's")
    parser.add_argument("--curves", default=None, choices=CURVES, help="default: the fast recipe's")
    parser.add_argument("--texture", default=None, choices=TEXTURES, help="default: the fast recipe's")
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "city100-default.safetensors")
    parser.add_argument("--name", default="city100-default", help="the profile's name")
    args = parser.parse_args()
    pairs = filter_pairs(discover_pairs(args.data / "pairs.csv").pairs, subset="city100_iPhoneX")
    fitted = [pair for pair in pairs if pair.scene <= LAST_FITTED_SCENE]
    held = [pair for pair in pairs if pair.scene > LAST_FITTED_SCENE]
    config = FitConfig.recipe(
        "fast", arch=args.arch, epochs=args.epochs, upsample=args.upsample, curves=args.curves, texture=args.texture
    )
    started = time.perf_counter()
    profile = fit_profile(
        PairSet.load(fitted), config, name=args.name, description=DESCRIPTION, log=print, progress=True
    )
    fit_seconds = time.perf_counter() - started
    print(f"fit: {fit_seconds:.0f} s")
    print(json.dumps(profile.quality, indent=1))
    profile.quality = {**held_out_quality(profile, held), "validation": profile.quality}
    profile.fitted |= {
        "data": "City100_iPhoneX (Chen et al. CVPR 2019, MIT), REAL pairs of scenes 001-055",
        "held_out_data": f"City100_iPhoneX scenes {', '.join(pair.scene for pair in held)} (never used)",
        "command": " ".join(
            ["python experiments/fit_city100_default.py", f"--arch {args.arch}", f"--out {args.out}"]
            + [
                f"--{key} {value}"
                for key, value in vars(args).items()
                if key in ("epochs", "upsample", "curves", "texture") and value is not None
            ]
            + [f"--name {args.name}"]
        ),
        "fit_seconds": round(fit_seconds),  # the whole fit_profile call: pairs loaded, network, stages, fidelity
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    profile.save(args.out)
    print(json.dumps(profile.quality, indent=1))
    print(f"wrote {args.out}")


def held_out_quality(profile, held) -> dict:
    """PSNR of the clean image, the network, the sampled profile (seed = scene index, as training sees it) and its
    deterministic output against the held-out captures, and the fidelity of the sampled profile with 8 critics (4
    seeds, each trained on half the held-out scenes and scored on the other half, and back)."""
    sims, reals, cleans, identity, sampled, network, means = [], [], [], [], [], [], []
    for index, pair in enumerate(held):
        clean, real = (as_unit(image) for image in load_pair(pair))
        sim = as_unit(CameraDegrade(profile, seed=index)(load_pair(pair)[0]))
        sims.append(sim), reals.append(real), cleans.append(clean)
        identity.append(psnr(clean, real)), sampled.append(psnr(sim, real))
        with torch.no_grad():
            network.append(psnr(profile.network(clean[None])[0], real))
            means.append(psnr(profile.simulate([clean], index, deterministic=True)[0], real))
    fidelity = measure_fidelity(sims, reals, cleans).to_dict(digits=3)
    fidelity.pop("psnr")  # profile_psnr_db
    scenes = [pair.scene for pair in held]
    for key, image_only in (("critic_paired", False), ("critic_image_only", True)):
        result = repeated_critic_test((cleans, reals, sims), scenes, CRITIC_SEEDS, image_only=image_only)
        fidelity[key] = result.to_dict()
    print(f"held-out ({len(held)} scenes): sampled {mean(sampled):.2f} dB, network {mean(network):.2f} dB")
    return {
        "held_out_pairs": len(held),
        "held_out": "City100 iPhone X scenes 056-070, 098 (REAL captures; never used in the fit)",
        "identity_psnr_db": mean(identity),
        "network_psnr_db": mean(network),
        "profile_psnr_db": mean(sampled),
        "profile_psnr_mean_db": mean(means),  # the deterministic output: the conditional mean
        "fidelity": fidelity,
    }


def mean(values: list[float]) -> float:
    return round(sum(values) / len(values), 3)


if __name__ == "__main__":
    main()
