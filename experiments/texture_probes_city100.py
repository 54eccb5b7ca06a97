"""Would the captures' texture fool the image-only critic? Post-hoc changes of the built-in's output that give it
more of the captures' power at 0.08–0.35 cycles/pixel, measured on the 16 held-out City100 scenes (056–070, 098).

Rows (each applied to ``city100-iphonex`` sampled as training sees it, then rounded to 8 bits):

- the built-in as it is;
- its luma spectrum equalized to the captures': per radial bin of 0.005 cycles/pixel the gain
  ``sqrt(power of the captures / power of the built-in)`` over the frames of scenes 001–024 (fitting scenes, not
  held out), smoothed over 3 bins and clipped to [1/4, 4], applied to the luma by FFT over the whole frame;
- a band-pass boost of the luma: ``+ amount · (G_σ1 ⊛ Y − G_σ2 ⊛ Y)`` (difference of Gaussians).

Each row gets the fidelity measures and 8 critics per mode (4 seeds, each trained on the even scenes and scored on
the odd ones, and back; :func:`~camdegrade.measures.critic.repeated_critic_test`). None of these is a stage of
the package: they ask whether the power the built-in lacks is what the critic reads (docs/results.md). Run from
the repo root (about 7 minutes on 2 cores)::

    OMP_NUM_THREADS=2 .venv/bin/python experiments/texture_probes_city100.py
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade import CameraDegrade, load_profile
from camdegrade._support.pixels import as_unit
from camdegrade.fitting import discover_pairs, filter_pairs, load_pair
from camdegrade.functional import blur_image
from camdegrade.functional.analysis.images import hann2d, luma
from camdegrade.measures.critic import repeated_critic_test
from camdegrade.measures.fidelity import measure_fidelity
from camdegrade.measures.metrics import psnr

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real-pairs"
HELD_OUT = {f"{n:03d}" for n in range(56, 71)} | {"098"}
CALIBRATION = {f"{n:03d}" for n in range(1, 25)}
BINS = 100  # of 0.005 cycles/pixel up to 0.5
MIN_GAIN, MAX_GAIN = 0.25, 4.0
DOG = ((0.6, 1.2, 1.0), (0.8, 1.6, 1.5))  # (σ1, σ2, amount)
CRITIC_SEEDS = 4


def bins_of(height: int, width: int) -> Tensor:
    """``(H, W)``: the radial bin of each frequency of a full 2-D FFT (``BINS - 1`` at and beyond 0.5)."""
    radius = torch.sqrt(torch.fft.fftfreq(height)[:, None] ** 2 + torch.fft.fftfreq(width)[None, :] ** 2)
    return (radius / 0.5 * BINS).long().clamp(max=BINS - 1)


def binned_power(image: Tensor) -> Tensor:
    """``(BINS,)`` summed luma power (Hann window, mean removed) per radial bin of a ``(3, H, W)`` image."""
    gray = luma(image[None]).reshape(image.shape[-2:]) * 255.0
    gray = gray - gray.mean()
    power = torch.fft.fft2(gray * hann2d(*gray.shape)).abs().pow(2).double()
    return torch.bincount(bins_of(*gray.shape).flatten(), weights=power.flatten(), minlength=BINS)


def equalizing_gain(sims: list[Tensor], reals: list[Tensor]) -> Tensor:
    """``(BINS,)`` amplitude gain taking the luma power of ``sims`` to that of ``reals``, smoothed and clipped."""
    ratio = sum(binned_power(r) for r in reals) / sum(binned_power(s) for s in sims)
    gain = ratio.sqrt().clamp(MIN_GAIN, MAX_GAIN)
    kernel = torch.tensor([0.25, 0.5, 0.25], dtype=torch.float64).view(1, 1, 3)
    return F.conv1d(F.pad(gain[None, None], (1, 1), mode="replicate"), kernel)[0, 0]


def equalized(image: Tensor, gain: Tensor) -> Tensor:
    """``image`` with its luma filtered by the radial ``gain`` (the chroma kept)."""
    gray = luma(image[None]).reshape(image.shape[-2:])
    filtered = torch.fft.ifft2(torch.fft.fft2(gray) * gain[bins_of(*gray.shape)].float()).real
    return (image + (filtered - gray)[None]).clamp(0, 1)


def band_boosted(image: Tensor, sigma1: float, sigma2: float, amount: float) -> Tensor:
    """``image + amount · (G_σ1 ⊛ Y − G_σ2 ⊛ Y)`` on the luma ``Y`` (the same detail added to R, G and B)."""
    gray = luma(image[None]).reshape(1, 1, *image.shape[-2:]).expand(1, 3, *image.shape[-2:])
    detail = blur_image(gray, sigma1) - blur_image(gray, sigma2)
    return (image + amount * detail[0]).clamp(0, 1)


def eight_bit(image: Tensor) -> Tensor:
    return (image.clamp(0, 1) * 255).round() / 255


def sampled(profile, pairs) -> tuple[list[Tensor], list[Tensor], list[Tensor]]:
    """``(cleans, reals, sims)`` in [0, 1]: the profile sampled with seed = index, as training sees it."""
    cleans, reals, sims = [], [], []
    for index, pair in enumerate(pairs):
        clean, real = load_pair(pair)
        cleans.append(as_unit(clean)), reals.append(as_unit(real))
        sims.append(as_unit(CameraDegrade(profile, seed=index)(clean)))
    return cleans, reals, sims


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    args = parser.parse_args()
    profile = load_profile("city100-iphonex")
    pairs = filter_pairs(discover_pairs(args.data / "pairs.csv").pairs, subset="city100_iPhoneX")
    _, calibration_reals, calibration_sims = sampled(profile, [p for p in pairs if p.scene in CALIBRATION])
    gain = equalizing_gain(calibration_sims, calibration_reals)
    held = [pair for pair in pairs if pair.scene in HELD_OUT]
    cleans, reals, sims = sampled(profile, held)
    scenes = [pair.scene for pair in held]
    rows = {"built-in": sims, "luma spectrum equalized": [equalized(sim, gain) for sim in sims]}
    for sigma1, sigma2, amount in DOG:
        rows[f"luma band boost σ {sigma1}/{sigma2} × {amount}"] = [
            band_boosted(s, sigma1, sigma2, amount) for s in sims
        ]
    for name, images in rows.items():
        images = [eight_bit(image) for image in images]
        fidelity = measure_fidelity(images, reals, cleans).to_dict(digits=3)
        row = {"row": name, "psnr": round(sum(psnr(i, r) for i, r in zip(images, reals)) / len(images), 2)}
        row |= {key: fidelity[key] for key in ("grid_ratio", "bands", "noise_ratio", "banding_ratio")}
        for mode, image_only in (("paired", False), ("image_only", True)):
            result = repeated_critic_test((cleans, reals, images), scenes, CRITIC_SEEDS, image_only=image_only)
            row[mode] = {key: round(getattr(result, key), 3) for key in ("accuracy", "std", "low", "high")}
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
