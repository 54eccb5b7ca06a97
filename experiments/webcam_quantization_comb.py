"""Is the foreign webcam's 5-bit buffer measurable through its 2× bicubic zoom? (issue 42, the quantization scenario)

The webcam of ``tests/foreign_cameras`` quantizes its sensor image to 5 bits before its tone table, then its ISP
zooms the 8-bit buffer 2× by PIL bicubic. On the scenario's diagnosis pairs (24 of 128², scene seed of
``bench/bench_foreign_diagnosis.py``) and the control's, the comb of the 8-bit code histogram
(:func:`~camdegrade.functional.isp.quantization.histogram_comb`: 0 smooth, 1.7 for a 5-bit buffer) per channel:

- **output**: of the captures as they are;
- **sensor**: of the sensor image recovered by least squares from each capture (the 2× PIL bicubic upscale is a
  linear map ``U`` of full column rank, built here by resizing unit impulses with PIL; the estimate is
  ``pinv(U) · x · pinv(U)ᵀ`` per channel, rounded), with how well ``U`` maps it back onto the capture.

Then, on the diagnosis' held-out half of the scenario (split by scene, seed 0, as ``diagnose`` splits them), the
``add quantization`` candidate as the diagnosis fits it on the calibration half, and the same stage with the camera's
own 32 levels (its tone table at the 5-bit codes): their levels, combs, the ``comb`` family and the held-out gap.

Run from the repo root::

    PYTHONPATH=src:tests OMP_NUM_THREADS=1 .venv/bin/python experiments/webcam_quantization_comb.py --out /tmp/fd
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

from foreign_bench import DIAGNOSIS_SEED, OTHER_PHOTOS, make_pairs

from camdegrade import load_profile
from camdegrade.diagnose.attribution.changes import KINDS
from camdegrade.diagnose.attribution.search import Round, Search
from camdegrade.diagnose.heldout import Baseline, HeldOut
from camdegrade.effects import Quantization
from camdegrade.functional.isp.quantization import code_histogram, histogram_comb
from camdegrade.measures import family_gaps
from camdegrade.pairs.pairset import PairSet
from camdegrade.profile import CameraProfile
from foreign_cameras import SCENARIOS
from foreign_cameras.stages import ToneLUT


def upsampling(size: int) -> np.ndarray:
    """``(2 size, size)``: PIL's bicubic 2× upscale of a row, column ``j`` the upscale of the unit impulse at ``j``."""
    columns = []
    for index in range(size):
        impulse = np.zeros((1, size), np.float32)
        impulse[0, index] = 1.0
        columns.append(np.asarray(Image.fromarray(impulse, "F").resize((2 * size, 1), Image.BICUBIC))[0])
    return np.stack(columns, 1).astype(np.float64)


def sensor_image(image: torch.Tensor, inverse: np.ndarray) -> torch.Tensor:
    """The least-squares sensor image of an upscaled ``(3, H, W)`` 8-bit ``image``, rounded to 8-bit codes."""
    planes = image.double().numpy() * (255.0 if image.dtype != torch.uint8 else 1.0)
    estimate = np.stack([inverse @ plane @ inverse.T for plane in planes])
    return torch.from_numpy(np.clip(np.round(estimate), 0, 255).astype(np.uint8))


def combs(images: list[torch.Tensor], inverse: np.ndarray) -> tuple[list[float], list[float]]:
    """Per channel, the comb of ``images``' codes and of their sensor images'."""
    output = histogram_comb(sum(code_histogram(image) for image in images))
    sensor = histogram_comb(sum(code_histogram(sensor_image(image, inverse)) for image in images))
    return [[round(float(v), 3) for v in num / den] for num, den in (output, sensor)]  # type: ignore[return-value]


def captures(inverse: np.ndarray, upscale: np.ndarray) -> None:
    print("| scenario | comb of the output (R, G, B) | comb at the sensor's resolution | U · estimate − capture |")
    print("|---|---|---|---:|")
    for scenario in ("control", "quantization"):
        made = make_pairs(SCENARIOS["webcam"][scenario].camera(), 24, 128, DIAGNOSIS_SEED, OTHER_PHOTOS)
        real = [captured for _, captured in made]
        output, sensor = combs(real, inverse)
        mapped = [
            np.stack([upscale @ plane @ upscale.T for plane in sensor_image(x, inverse).double().numpy()]) for x in real
        ]
        residual = np.mean([np.abs(back - x.double().numpy()).mean() for back, x in zip(mapped, real, strict=True)])
        print(f"| {scenario} | {output} | {sensor} | {residual:.2f} levels |")


def candidates(profile: CameraProfile, inverse: np.ndarray) -> None:
    made = make_pairs(SCENARIOS["webcam"]["quantization"].camera(), 24, 128, DIAGNOSIS_SEED, OTHER_PHOTOS)
    calibration, held_set = PairSet.load(made).split(0.5, 0)
    held = HeldOut.build(held_set.unit_pairs(), 0, "held-out")
    baseline = Baseline.measure(held, profile)
    search = Search(profile, calibration.unit_pairs(), held, baseline, 0)
    round_ = Round(search, profile, baseline.stats, baseline.gap, [], lambda line: None)
    fitted_profile, fitted, _ = KINDS["add"].make(round_, "quantization")
    table = ToneLUT(contrast=0.25).table()
    own = torch.tensor(table[np.round(np.arange(32) * 255 / 31).astype(int)] / 255.0, dtype=torch.float32)
    camera_levels = Quantization(32, own.repeat(3, 1), 0.5)
    print(f"held-out captures: comb output / sensor {combs(held.reals, inverse)}")
    rows = (("as fitted", profile, None), ("add quantization", fitted_profile, fitted))
    rows += (("the camera's 32 levels", profile.with_effects(camera_levels), camera_levels),)
    for label, changed, stage in rows:
        stats, sims = held.statistics(changed)
        levels = "" if stage is None else f"{len(set(stage.codebook[1].tolist()))} levels at scale {float(stage.scale)}"
        comb = family_gaps(held.real, stats, scale=held.scale)["comb"]
        print(f"{label} ({levels}): comb {combs(sims, inverse)}, comb family {comb:.2f}, gap {held.gap(stats):.2f}")
    print("fitted green levels:", [round(v * 255) for v in sorted(set(fitted.codebook[1].tolist()))])
    print("camera green levels:", [round(v * 255) for v in own.tolist()])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=Path("/tmp/foreign"))
    args = parser.parse_args()
    torch.set_num_threads(1)
    upscale = upsampling(64)
    inverse = np.linalg.pinv(upscale)
    captures(inverse, upscale)
    candidates(load_profile(args.out / "fits" / "webcam-64x128.safetensors"), inverse)
    return 0


if __name__ == "__main__":
    sys.exit(main())
