"""Evidence on real data: City100 iPhone X held-out PSNR/SSIM of identity, the best-fitted parametric effect chain,
the paper's network, and the network + fitted effects.

Data: the REAL City100 iPhone X pairs in ``../shared/data/real-pairs`` beside the checkout (or ``--data``), read
in place. Split by scene: every effect stage is fitted on the train scenes 001–055 (the network's own training
scenes 001–047 and its validation scenes 048–055); the numbers are on the 16 held-out scenes 056–070 and 098,
never used in any fit. Choices (which parametric chain, which stages to add after the network) are made on
train-scene PSNR only.

Rows with a noise stage are reported twice: ``mean`` skips the noise stage (the deterministic prediction) and
``sampled`` draws the noise from a fixed seed. Paired PSNR penalises correct noise (an independent noise draw
adds its variance to the error), so comparisons use the ``mean`` columns. Run from the repo root::

    OMP_NUM_THREADS=1 .venv/bin/python experiments/city100_evidence.py \\
        --write-profile src/camdegrade/profiles/city100-iphonex.safetensors
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import platform
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from camdegrade import CameraProfile, load_profile
from camdegrade.effects import EFFECTS, Effect, Noise
from camdegrade.fitting import discover_pairs, filter_pairs, load_pair
from camdegrade.fitting.in_chain import fit_noise_stage
from camdegrade.measures.metrics import psnr, ssim

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real-pairs"
HELD_OUT = {f"{n:03d}" for n in range(56, 71)} | {"098"}
TRAIN = {f"{n:03d}" for n in range(1, 56)}
#: Candidate parametric chains (each stage fitted on the previous stage's output), in physical order.
CHAINS: dict[str, tuple[str, ...]] = {
    "blur+color+tone": ("blur", "color", "tone"),
    "blur+tone+color": ("blur", "tone", "color"),
    "vignetting+blur+color+tone": ("vignetting", "blur", "color", "tone"),
    "blur(anisotropic)+color+tone": ("blur_anisotropic", "color", "tone"),
    "color+tone": ("color", "tone"),
    "blur+color": ("blur", "color"),
}
#: Deterministic stages tried after the network, in physical order; each kept only if it lowers train MSE ≥ 1 %.
AFTER_NETWORK = ("vignetting", "blur", "color", "tone")
MIN_RELATIVE_GAIN = 0.01

Images = list[Tensor]


def load_scenes(data: Path, keep: set[str]) -> tuple[list[str], Images, Images]:
    """Scene ids and float [0, 1] (clean, captured) lists for the City100 iPhone X scenes in ``keep``."""
    report = discover_pairs(data / "pairs.csv")
    pairs = {pair.scene: pair for pair in filter_pairs(report.pairs, subset="city100_iPhoneX")}
    scenes = sorted(scene for scene in pairs if scene in keep)
    if len(scenes) != len(keep):
        raise SystemExit(f"expected {len(keep)} City100 iPhone X scenes in {data / 'pairs.csv'}, found {len(scenes)}")
    clean, captured = [], []
    for scene in scenes:
        a, b = load_pair(pairs[scene])
        clean.append(a.float() / 255)
        captured.append(b.float() / 255)
    return scenes, clean, captured


def fit_stage(name: str, source: Images, target: Images) -> Effect:
    if name == "blur_anisotropic":
        return EFFECTS["blur"].fit(source, target, anisotropic=True)
    return EFFECTS[name].fit(source, target)


@torch.no_grad()
def apply(stages: Sequence[torch.nn.Module], images: Images) -> Images:
    out = []
    for image in images:
        x = image[None]
        for stage in stages:
            x = stage(x) if not isinstance(stage, Effect) else stage(x, stage.make_params(x.shape))
        out.append(x[0].clamp(0, 1))
    return out


def mse(predictions: Images, targets: Images) -> float:
    total = sum(float((p - t).pow(2).sum()) for p, t in zip(predictions, targets))
    return total / sum(t.numel() for t in targets)


def mean_psnr(predictions: Images, targets: Images) -> float:
    return sum(psnr(p, t) for p, t in zip(predictions, targets)) / len(targets)


def fit_chain(names: Sequence[str], clean: Images, captured: Images, cache: dict) -> list[Effect]:
    """Fit each stage on the output of the previous ones (prefixes are cached across candidate chains)."""
    effects: list[Effect] = []
    current = clean
    for depth in range(len(names)):
        key = tuple(names[: depth + 1])
        if key not in cache:
            cache[key] = fit_stage(names[depth], current, captured)
        effects.append(cache[key])
        current = apply([cache[key]], current)
    return effects


def fit_noise(profile: CameraProfile, clean: Images, captured: Images) -> Noise:
    """The noise stage for ``profile``: fitted where the clean image is flat (the variance the deterministic
    prediction lacks), then calibrated by simulating the profile with it (``camdegrade.fitting.in_chain``)."""
    return fit_noise_stage(profile, clean, captured, calibration_pairs=20)


@torch.no_grad()
def evaluate(profile: CameraProfile, clean: Images, captured: Images, seed: int) -> dict[str, Any]:
    """Held-out PSNR/SSIM: ``mean`` (noise stages skipped) and, when the profile has noise, ``sampled``."""
    deterministic = profile.without_randomness()
    generator = torch.Generator().manual_seed(seed)
    result: dict[str, Any] = {"psnr_mean": [], "ssim_mean": []}
    noisy = len(deterministic.effects) < len(profile.effects)
    if noisy:
        result |= {"psnr_sampled": [], "ssim_sampled": [], "residual_std_mean": [], "residual_std_sampled": []}
    for image, target in zip(clean, captured):
        x = image[None]
        mean_out = deterministic(x, deterministic.make_params(x.shape))[0]
        result["psnr_mean"].append(psnr(mean_out, target))
        result["ssim_mean"].append(ssim(mean_out, target))
        if noisy:
            sampled = profile(x, profile.make_params(x.shape, generator))[0]
            result["psnr_sampled"].append(psnr(sampled, target))
            result["ssim_sampled"].append(ssim(sampled, target))
            # the noise the profile adds vs the residual it has to explain (both around the mean prediction)
            result["residual_std_mean"].append(float((target - mean_out).std()))
            result["residual_std_sampled"].append(float((sampled - mean_out).std()))
    return {key: round(sum(values) / len(values), 4) for key, values in result.items()}


def greedy_after_network(
    network: torch.nn.Module, clean: Images, captured: Images, say: Callable[[str], None]
) -> tuple[list[Effect], dict[str, Any]]:
    """Fit each stage of :data:`AFTER_NETWORK` on the current train-scene output; keep it if MSE drops ≥ 1 %."""
    current = apply([network], clean)
    before = mse(current, captured)
    kept: list[Effect] = []
    notes: dict[str, Any] = {}
    for name in AFTER_NETWORK:
        effect = fit_stage(name, current, captured)
        candidate = apply([effect], current)
        after = mse(candidate, captured)
        gain = 1 - after / before
        keep = gain >= MIN_RELATIVE_GAIN
        notes[name] = {"kept": keep, "relative_train_mse_gain": round(gain, 4), "fit": effect.extra_repr()}
        say(f"  after network: {name} train MSE gain {gain:+.2%} -> {'kept' if keep else 'dropped'}")
        if keep:
            kept.append(effect)
            current, before = candidate, after
    noise = fit_noise(CameraProfile(network, kept), clean, captured)
    notes["noise"] = {
        "kept": True,
        "fit": noise.extra_repr(),
        "std_at_mid_grey_levels": round(noise.magnitude(), 3),
        "fitted_on": "train scenes where the clean image is flat (absolute threshold), excess over the prediction, "
        "calibrated through the chain",
    }
    say(f"  after network: noise {noise.extra_repr()}")
    return [*kept, noise], notes


def build(network: torch.nn.Module | None, deterministic: Sequence[Effect], noise: Effect) -> CameraProfile:
    """A profile holding the deterministic stages, with noise inserted at its physical (sensor) position."""
    return CameraProfile(copy.deepcopy(network), [copy.deepcopy(e) for e in deterministic]).with_effects(
        copy.deepcopy(noise)
    )


def machine() -> str:
    return (
        f"{platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__}, "
        f"{torch.get_num_threads()} torch thread(s)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--network", default="city100-iphonex", help="profile whose network is used (effects ignored)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the sampled noise")
    parser.add_argument("--json", type=Path, default=Path("out/results/city100.json"))
    parser.add_argument("--write-profile", type=Path, default=None, help="save network + fitted effects here")
    args = parser.parse_args()
    say = print
    started = time.perf_counter()

    _, train_clean, train_captured = load_scenes(args.data, TRAIN)
    held_scenes, held_clean, held_captured = load_scenes(args.data, HELD_OUT)
    say(f"City100 iPhone X: {len(train_clean)} train scenes (001-055), {len(held_scenes)} held-out (056-070, 098)")

    # Parametric chains: pick by train-scene PSNR of the deterministic prediction.
    cache: dict = {}
    candidates = {}
    for label, names in CHAINS.items():
        effects = fit_chain(names, train_clean, train_captured, cache)
        train_db = mean_psnr(apply(effects, train_clean), train_captured)
        candidates[label] = {"effects": effects, "train_psnr_db": round(train_db, 3)}
        say(f"  chain {label:30s} train PSNR {train_db:.3f} dB  " + "; ".join(e.extra_repr() for e in effects))
    best_label = max(candidates, key=lambda k: candidates[k]["train_psnr_db"])
    chain = candidates[best_label]["effects"]
    chain_noise = fit_noise(CameraProfile(None, chain), train_clean, train_captured)
    chain_profile = build(None, chain, chain_noise)
    say(f"best parametric chain on train scenes: {best_label}; noise {chain_noise.extra_repr()}")

    # The paper's network, and network + stages fitted on its train-scene residuals.
    base = load_profile(args.network)
    network = base.network
    if network is None:
        raise SystemExit(f"profile {args.network!r} has no network")
    after_effects, after_notes = greedy_after_network(network, train_clean, train_captured, say)
    full_profile = build(network, after_effects[:-1], after_effects[-1])
    full_train = mean_psnr(apply([network, *after_effects[:-1]], train_clean), train_captured)

    rows = {
        "identity": evaluate(CameraProfile(None, []), held_clean, held_captured, args.seed),
        f"parametric chain ({best_label} + noise)": evaluate(chain_profile, held_clean, held_captured, args.seed),
        "network (paper)": evaluate(CameraProfile(network, []), held_clean, held_captured, args.seed),
        "network + fitted effects": evaluate(full_profile, held_clean, held_captured, args.seed),
    }
    labels = list(rows)
    chain_row, network_row, full_row = rows[labels[1]], rows[labels[2]], rows[labels[3]]
    best_learned = max(network_row["psnr_mean"], full_row["psnr_mean"])
    margin = round(best_learned - chain_row["psnr_mean"], 3)
    minutes = (time.perf_counter() - started) / 60

    say("")
    say(f"{'row':45s} {'PSNR mean':>10s} {'SSIM mean':>10s} {'PSNR sampled':>13s} {'SSIM sampled':>13s}")
    for label, row in rows.items():
        sampled = (
            f"{row['psnr_sampled']:13.2f} {row['ssim_sampled']:13.3f}" if "psnr_sampled" in row else f"{'-':>13s} " * 2
        )
        say(f"{label:45s} {row['psnr_mean']:10.2f} {row['ssim_mean']:10.3f} {sampled}")
    say(f"margin of the learned profile over the parametric chain (mean columns): {margin:+.2f} dB")
    for label in labels[1:]:
        if "residual_std_mean" in rows[label]:
            say(
                f"{label}: held-out residual std {rows[label]['residual_std_mean']:.4f}, "
                f"added noise std {rows[label]['residual_std_sampled']:.4f}"
            )
    say(f"{minutes:.1f} min on {machine()}")

    results = {
        "data": "City100_iPhoneX REAL pairs; effects fitted on train scenes 001-055; held-out 056-070, 098",
        "held_out_pairs": len(held_scenes),
        "rows": rows,
        "parametric_candidates_train_psnr_db": {k: v["train_psnr_db"] for k, v in candidates.items()},
        "parametric_chain": {
            "chosen": best_label,
            "effects": [{"name": e.name, "fit": e.extra_repr()} for e in chain_profile.effects],
        },
        "network_from": args.network,
        "after_network": after_notes,
        "network_plus_effects_train_psnr_db": round(full_train, 3),
        "margin_db": margin,
        "seed": args.seed,
        "minutes": round(minutes, 2),
        "machine": machine(),
        "command": "OMP_NUM_THREADS=1 .venv/bin/python experiments/city100_evidence.py"
        + (f" --write-profile {args.write_profile}" if args.write_profile else ""),
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(results, indent=2) + "\n")
    say(f"wrote {args.json}")

    if args.write_profile is not None:
        write_profile(base, full_profile, rows, results, args.write_profile)
        say(f"wrote {args.write_profile} ({args.write_profile.stat().st_size / 1024:.0f} KiB)")


def write_profile(
    base: CameraProfile, full: CameraProfile, rows: dict[str, dict], results: dict[str, Any], path: Path
) -> None:
    """Save network + fitted effects, keeping the network's fitting record and adding the effects and evidence."""
    labels = list(rows)
    identity, chain, network, profile = (rows[label] for label in labels)
    fitted = dict(base.fitted)
    fitted["effects"] = results["after_network"]
    fitted["effects_fitted_on"] = (
        "network output vs capture on train scenes 001-055 (stages kept if MSE -1 %); noise on flat pixels only"
    )
    fitted["effects_command"] = results["command"]
    fitted["effects_script"] = "experiments/city100_evidence.py"
    note = fitted.get("history_note", "")
    addition = (
        "effect stages fitted afterwards on the network's train-scene residuals by experiments/city100_evidence.py"
    )
    if addition not in note:
        fitted["history_note"] = f"{note}; {addition}" if note else addition
    quality = dict(base.quality)
    quality |= {
        "held_out_pairs": results["held_out_pairs"],
        "identity_psnr_db": round(identity["psnr_mean"], 3),
        "identity_ssim": round(identity["ssim_mean"], 3),
        "network_psnr_db": round(network["psnr_mean"], 3),
        "network_ssim": round(network["ssim_mean"], 3),
        "profile_mean_psnr_db": round(profile["psnr_mean"], 3),
        "profile_mean_ssim": round(profile["ssim_mean"], 3),
        "profile_sampled_psnr_db": round(profile["psnr_sampled"], 3),
        "profile_sampled_ssim": round(profile["ssim_sampled"], 3),
        "parametric_chain": results["parametric_chain"]["chosen"] + " + noise",
        "parametric_chain_psnr_db": round(chain["psnr_mean"], 3),
        "parametric_chain_ssim": round(chain["ssim_mean"], 3),
        "margin_over_parametric_db": results["margin_db"],
        "evidence": "docs/results.md",
    }
    shipped = CameraProfile(
        full.network,
        list(full.effects),
        name="city100-iphonex",
        description=base.description,
        fitted=fitted,
        quality=quality,
    )
    shipped.save(path)


if __name__ == "__main__":
    main()
