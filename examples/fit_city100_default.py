"""A default fit (``fit_profile`` with the fast recipe: ``arch="local_affine"``) of the City100 iPhone X, scored on
the 16 held-out scenes — the numbers issue 23's architecture step rests on.

Fits on the REAL pairs of scenes 001–055 (``fit_profile`` splits off 15 % of them by scene to validate), writes the
profile, and prints its ``quality`` (validation PSNR of the identity, the least-squares linear baseline, the network
and the sampled profile; fidelity numbers) and, on the held-out scenes 056–070 and 098 (never used in the fit), the
paired PSNR of the sampled profile and of its network alone, and :func:`~camdegrade.measures.measure_fidelity`.
Compare it with the built-ins in one table with ``examples/fidelity_city100.py --profile "default fit=OUT"``. Run
from the repo root::

    OMP_NUM_THREADS=2 .venv/bin/python examples/fit_city100_default.py [--arch local_affine] [--out PATH] \
        [--upsample smooth] [--texture none]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from camdegrade import CameraDegrade
from camdegrade._pixels import as_unit
from camdegrade._recipes import TEXTURES, UPSAMPLINGS
from camdegrade.fitting import FitConfig, PairSet, discover_pairs, filter_pairs, fit_profile, load_pair
from camdegrade.measures.fidelity import measure_fidelity
from camdegrade.metrics import psnr

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DATA = ROOT.parent / "shared" / "data" / "real-pairs"
LAST_FITTED_SCENE = "055"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--arch", default="local_affine", choices=("local_affine", "paper"))
    parser.add_argument("--epochs", type=int, default=None, help="default: the fast recipe's")
    parser.add_argument("--upsample", default=None, choices=UPSAMPLINGS, help="default: the fast recipe's")
    parser.add_argument("--texture", default=None, choices=TEXTURES, help="default: the fast recipe's")
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "city100-default.safetensors")
    args = parser.parse_args()
    pairs = filter_pairs(discover_pairs(args.data / "pairs.csv").pairs, subset="city100_iPhoneX")
    fitted = [pair for pair in pairs if pair.scene <= LAST_FITTED_SCENE]
    held = [pair for pair in pairs if pair.scene > LAST_FITTED_SCENE]
    config = FitConfig.recipe("fast", arch=args.arch, epochs=args.epochs, upsample=args.upsample, texture=args.texture)
    started = time.perf_counter()
    profile = fit_profile(PairSet.load(fitted), config, name="city100-default", log=print, progress=True)
    print(f"fit: {time.perf_counter() - started:.0f} s")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    profile.save(args.out)
    print(json.dumps(profile.quality, indent=1))
    sims, reals, cleans, sampled, network = [], [], [], [], []
    for index, pair in enumerate(held):
        clean, real = (as_unit(image) for image in load_pair(pair))
        sim = as_unit(CameraDegrade(profile, seed=index)(load_pair(pair)[0]))
        sims.append(sim), reals.append(real), cleans.append(clean)
        sampled.append(psnr(sim, real))
        with torch.no_grad():
            network.append(psnr(profile.network(clean[None])[0], real))
    mean_sampled, mean_network = sum(sampled) / len(sampled), sum(network) / len(network)
    print(f"held-out ({len(held)} scenes): sampled {mean_sampled:.2f} dB, network {mean_network:.2f} dB")
    print(json.dumps(measure_fidelity(sims, reals, cleans).to_dict(digits=3)))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
