"""Fit the built-in ``city100-iphonex`` profile on the REAL City100 iPhone X pairs and report held-out quality.

The pairs (``../shared/data/real-pairs`` beside the checkout, or ``--data``) are never copied into the repo.
Split by scene: train 001–047, validation (best-epoch choice) 048–055, held-out 056–070 and 098 (never seen
during fitting). Run from the repo root::

    .venv/bin/python experiments/fit_city100.py --out out/city100-iphonex.safetensors   # the network
    .venv/bin/python experiments/city100_evidence.py --write-profile src/camdegrade/profiles/city100-iphonex.safetensors
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import torch

from camdegrade import CameraProfile
from camdegrade.fitting import FitConfig, Pair, discover_pairs, filter_pairs, load_pair
from camdegrade.fitting.network.training import evaluate_psnr, fit_network
from camdegrade.measures.metrics import psnr, ssim

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real-pairs"
HELD_OUT = {f"{n:03d}" for n in range(56, 71)} | {"098"}
VALIDATION = {f"{n:03d}" for n in range(48, 56)}


def city100_iphone_pairs(data: Path) -> dict[str, Pair]:
    """scene → pair for the City100 iPhone X rows of ``pairs.csv`` (scene ``001`` for ``001H.PNG``/``001L.PNG``)."""
    report = discover_pairs(data / "pairs.csv")
    scenes = {pair.scene: pair for pair in filter_pairs(report.pairs, subset="city100_iPhoneX")}
    if not scenes:
        raise SystemExit(f"no City100 iPhone X pairs in {data / 'pairs.csv'}")
    return scenes


def load(pairs: dict[str, Pair], keep) -> list[tuple[torch.Tensor, torch.Tensor]]:
    return [load_pair(pair) for scene, pair in sorted(pairs.items()) if keep(scene)]


def held_out_quality(profile_net, pairs) -> dict[str, float]:
    identity_psnr = [psnr(clean, captured) for clean, captured in pairs]
    identity_ssim = [ssim(clean, captured) for clean, captured in pairs]
    outputs = []
    with torch.no_grad():
        for clean, _ in pairs:
            outputs.append(profile_net(clean[None].float() / 255.0)[0])
    net_psnr = [psnr(out, captured.float() / 255.0) for out, (_, captured) in zip(outputs, pairs)]
    net_ssim = [ssim(out, captured.float() / 255.0) for out, (_, captured) in zip(outputs, pairs)]

    def mean(values):
        return round(sum(values) / len(values), 3)

    return {
        "held_out_pairs": len(pairs),
        "identity_psnr_db": mean(identity_psnr),
        "identity_ssim": mean(identity_ssim),
        "network_psnr_db": mean(net_psnr),
        "network_ssim": mean(net_ssim),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--out", type=Path, default=Path("out/city100-iphonex.safetensors"))
    parser.add_argument("--recipe", choices=("paper", "fast"), default="paper", help="the built-in used 'paper'")
    parser.add_argument("--epochs", type=int, default=None, help="default: the recipe's")
    parser.add_argument("--crop", type=int, default=128)
    parser.add_argument("--crops-per-pair", type=int, default=4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--checkpoint", type=Path, default=Path("out/city100-iphonex.ckpt.safetensors"))
    parser.add_argument("--resume", action="store_true", help="continue from --checkpoint if it exists")
    args = parser.parse_args()

    scenes = city100_iphone_pairs(args.data)
    train = load(scenes, lambda s: s not in HELD_OUT and s not in VALIDATION)
    val = load(scenes, lambda s: s in VALIDATION)
    held_out = load(scenes, lambda s: s in HELD_OUT)
    config = FitConfig.recipe(
        args.recipe, epochs=args.epochs, crop=args.crop, crops_per_pair=args.crops_per_pair, seed=args.seed
    )
    print(f"pairs: train {len(train)}, validation {len(val)}, held-out {len(held_out)}; {config}", flush=True)

    started = time.perf_counter()

    def report(result):
        print(
            f"epoch {result.epoch:3d}  lr {result.lr:.5f}  loss {result.train_loss:.5f}  "
            f"val PSNR {result.val_psnr:.2f} dB{'  *' if result.is_best else ''}",
            flush=True,
        )

    network, history = fit_network(train, val, config, callback=report, checkpoint=args.checkpoint, resume=args.resume)
    minutes = (time.perf_counter() - started) / 60
    best = max(history, key=lambda r: r.val_psnr)
    quality = held_out_quality(network, held_out)
    quality["validation_psnr_db"] = round(evaluate_psnr(network, val), 3)
    profile = CameraProfile(
        network,
        name="city100-iphonex",
        description="iPhone X at a distance vs. close-up (City100, real lens/distance blur and tone shift)",
        fitted={
            "data": "City100_iPhoneX (Chen et al. CVPR 2019, MIT), REAL pairs",
            "train_scenes": len(train),
            "validation_scenes": len(val),
            "held_out_scenes": "056-070, 098",
            "recipe": config.training_dict(),
            "best_epoch": best.epoch,
            "fit_minutes": round(minutes, 1),
            "machine": f"{platform.machine()}, {torch.get_num_threads()} threads, torch {torch.__version__}",
            "script": "experiments/fit_city100.py",
        },
        quality=quality,
    )
    profile.save(args.out)
    print(json.dumps(quality, indent=2))
    print(f"wrote {args.out} (best epoch {best.epoch}, {minutes:.1f} min)")


if __name__ == "__main__":
    main()
