"""Issue 23's simulated cameras: does a default fit reproduce only what the camera does, and beat the simple answer?

Two virtual cameras (:class:`camdegrade.sim.VirtualCamera`) capture crops of scikit-image's photographs (nothing is
downloaded; training and held-out photographs never overlap):

- ``soft``: lens blur σ 0.7 (linear light), a 2× resolution loss, a tone curve, and NO sensor noise (8-bit only);
- ``dark``: exposure × 0.25 (−2 stops), a tone curve and sensor noise.

Each is fitted with ``fit_profile`` defaults (the fast recipe) on the training crops; on the held-out crops the script
prints the paired PSNR of the least-squares linear baseline (:mod:`camdegrade.fitting.baseline`) and of the profile
(network mean, and sampled), the fidelity numbers (:mod:`camdegrade.measures.fidelity`: grid ratio, five band log2
power ratios, flat-noise and banding ratios), the learned critic (paired and image-only, 0.5: cannot tell) for the
profile and for the baseline, the stages the fit kept, and — for ``soft`` — what ``diagnose`` accepts on held-out
pairs of the same camera (a profile that matches its camera should accept nothing). Run from the repo root::

    OMP_NUM_THREADS=2 .venv/bin/python examples/fidelity_simulated.py [--camera soft dark] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from photo_crops import HELD_OUT_PHOTOS, TRAIN_PHOTOS, photo_crops

from camdegrade import CameraDegrade
from camdegrade._pixels import as_unit
from camdegrade.diagnose import diagnose
from camdegrade.effects import Blur, Noise, Tone
from camdegrade.fitting import fit_profile
from camdegrade.fitting.baseline import apply_linear_baseline, fit_linear_baseline
from camdegrade.measures.critic import critic_test
from camdegrade.measures.fidelity import measure_fidelity
from camdegrade.metrics import psnr
from camdegrade.sim import VirtualCamera

CROP = 128


def camera(name: str) -> VirtualCamera:
    if name == "soft":
        return VirtualCamera([Blur(0.7), Tone(gamma=0.9, black=-0.02, white=0.95)], scale=0.5, name="soft")
    return VirtualCamera(
        [Tone(exposure=-2.0), Noise(a=0.0008, b=2e-5), Tone(gamma=0.85, black=0.0, white=0.9)], name="dark"
    )


def capture(cam: VirtualCamera, cleans: list[torch.Tensor], seed: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
    generator = torch.Generator().manual_seed(seed)
    return [(clean, cam(clean, generator=generator)) for clean in cleans]


def critics(sims, pairs, seed: int = 0) -> dict[str, float]:
    cleans = [as_unit(clean) for clean, _ in pairs]
    reals = [as_unit(real) for _, real in pairs]
    out = {}
    for label, image_only in (("critic_paired", False), ("critic_image_only", True)):
        result = critic_test(cleans, reals, sims, seed=seed, image_only=image_only)
        out[label] = round(result.accuracy, 3)
    return out


def evaluate(profile, baseline, pairs) -> dict:
    cleans = [as_unit(clean) for clean, _ in pairs]
    reals = [as_unit(real) for _, real in pairs]
    sampled = [as_unit(CameraDegrade(profile, seed=i)(clean)) for i, (clean, _) in enumerate(pairs)]
    with torch.no_grad():
        means = [profile.without_randomness()(c[None])[0] for c in cleans]
        linear = [apply_linear_baseline(*baseline, c[None])[0] for c in cleans]
    mean_psnr = lambda images: round(sum(psnr(a, b) for a, b in zip(images, reals)) / len(reals), 2)  # noqa: E731
    fidelity = measure_fidelity(sampled, reals, cleans).to_dict(digits=3)
    return {
        "psnr": {
            "identity": mean_psnr(cleans),
            "baseline": mean_psnr(linear),
            "mean": mean_psnr(means),
            "sampled": mean_psnr(sampled),
        },
        "fidelity": {
            key: fidelity[key] for key in ("grid_ratio", "bands", "noise_ratio", "banding_ratio", "flat_pixels")
        },
        "profile": critics(sampled, pairs),
        "baseline": critics(linear, pairs),
        "stages": profile.effect_names,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--camera", nargs="+", default=["soft", "dark"], choices=["soft", "dark"])
    parser.add_argument("--diagnose", action="store_true", help="also run diagnose on held-out pairs (soft)")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    train_cleans = photo_crops(TRAIN_PHOTOS, per_photo=10, size=CROP, seed=0)
    held_cleans = photo_crops(HELD_OUT_PHOTOS, per_photo=8, size=CROP, seed=1)
    results = {}
    for name in args.camera:
        cam = camera(name)
        train, held = capture(cam, train_cleans, seed=2), capture(cam, held_cleans, seed=3)
        started = time.perf_counter()
        profile = fit_profile(train, "fast", log=lambda line, label=name: print(f"  [{label}] {line}", flush=True))
        minutes = round((time.perf_counter() - started) / 60, 2)
        baseline = fit_linear_baseline(train)
        row = {"fit_minutes": minutes, **evaluate(profile, baseline, held)}
        if args.diagnose and name == "soft":
            report = diagnose(profile, train[: len(train) // 2], held_out=held, critic=False)
            row["diagnose_accepted"] = list(report.accepted)
        results[name] = row
        print(json.dumps({name: row}), flush=True)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
