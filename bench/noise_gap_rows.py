"""The data and the rows of the PSNR-gap bench (``bench_noise_gap.py``): each real-noise subset split into training
and held-out pairs, and what each row trains its denoiser on, fitted on the training pairs only.

- ``real``: the camera's own noisy captures;
- ``profile``: a profile fitted with :func:`camdegrade.fit_profile` (:data:`PROFILE_RECIPE`: the fast recipe cut to
  the time budget), network and stages, sampled;
- ``stage``: the noise stage alone on the clean image, an effects-only profile fitted by
  :meth:`camdegrade.effects.Noise.fit` (``estimator="residual"``: the clean image is the mean of many frames);
- ``gaussian``: white Gaussian noise of the real noise's std on the training pairs' flat pixels;
- ``poisson_gaussian``: per channel ``var = a·x + b`` of the sRGB value, fitted to the same pixels' variance per
  intensity bin (Foi et al. 2008, with the clean image as the expectation);
- ``stage_jitter`` (on request): the ``stage`` row with a per-capture gain (``Noise.gain_jitter``) whose log-std is
  that of the training captures' own noise levels (their flat-pixel std), for cameras and ISOs mixed in one set;
- ``oracle`` (on request): the ``stage`` row fitted on the **held-out** pairs themselves, not a model of the camera
  but the best one stationary noise stage can do on those images (the bar of issue 15 for subsets that mix cameras).

Every simulated image is rounded to 8 bits, as a saved training set would be.

References:
    A. Foi, M. Trimeche, V. Katkovnik, K. Egiazarian, "Practical Poissonian-Gaussian noise modeling and fitting for
    single-image raw-data", IEEE TIP 17(10), 2008.
"""

from __future__ import annotations

import copy
import csv
import re
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from camdegrade import fit_profile
from camdegrade._support.pixels import as_unit
from camdegrade._support.seeds import derived_generator
from camdegrade.effects import Noise
from camdegrade.fitting import FitConfig, PairSet
from camdegrade.functional.analysis.images import flat_mask
from camdegrade.functional.analysis.noise import BINS, NoiseSums
from camdegrade.io import read_image
from camdegrade.profile import CameraProfile

SUBSETS = ("polyu_real_noise", "cc15_nam_real_noise", "sidd_samples")
ROWS = ("real", "profile", "stage", "gaussian", "poisson_gaussian")
OPTIONAL_ROWS = ("stage_jitter", "oracle")
#: The profile's recipe: the fast recipe cut to the time budget (8 epochs of about :data:`CROPS_PER_EPOCH` windows,
#: at least 8 per pair, no early stopping, only the noise stage after the network).
PROFILE_RECIPE = FitConfig.recipe("fast").replace(epochs=8, patience=0, effects=("noise",))
CROPS_PER_EPOCH = 640


# -- data ------------------------------------------------------------------------------------------------------------


@dataclass
class Split:
    """One subset's pairs (uint8 ``(3, H, W)``, ``(clean, capture)``), split into training and held-out pairs."""

    train: list[tuple[Tensor, Tensor]] = field(default_factory=list)
    test: list[tuple[Tensor, Tensor]] = field(default_factory=list)
    train_scenes: list[str] = field(default_factory=list)
    test_names: list[str] = field(default_factory=list)

    def unit(self, part: str) -> tuple[list[Tensor], list[Tensor]]:
        """``part``'s clean images and captures as float in [0, 1]."""
        pairs = self.train if part == "train" else self.test
        return [as_unit(c) for c, _ in pairs], [as_unit(x) for _, x in pairs]


def scene_of(subset: str, clean_path: str) -> str:
    """PolyU: camera, settings and scene without the crop number (``..._plant__4`` and ``..._plant_4`` are one
    scene); CC15 and SIDD: the image itself."""
    stem = Path(clean_path).stem.removesuffix("_mean")
    return re.sub(r"_+\d+$", "", stem) if subset == "polyu_real_noise" else stem


def held_out(subset: str, names: set[str]) -> set[str]:
    """Every fifth of PolyU's 30 scenes, every third image of CC15 and SIDD (natural order, from the second)."""
    every = 5 if subset == "polyu_real_noise" else 3
    return {name for index, name in enumerate(sorted(names, key=_natural)) if index % every == 1}


def _natural(name: str) -> list[Any]:
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]


@cache
def load_split(root: Path, subset: str) -> Split:
    """The subset's pairs as ``pairs.csv`` lists them (read once per process)."""
    with open(root / "pairs.csv", newline="") as handle:
        rows = [row for row in csv.DictReader(handle) if row["subset"] == subset]
    scenes = [scene_of(subset, row["clean"]) for row in rows]
    test_scenes = held_out(subset, set(scenes))
    split = Split()
    for row, scene in zip(rows, scenes, strict=True):
        pair = (read_image(root / row["clean"]), read_image(root / row["captured"]))
        if scene in test_scenes:
            split.test.append(pair)
            split.test_names.append(Path(row["clean"]).stem.removesuffix("_mean"))
        else:
            split.train.append(pair)
            split.train_scenes.append(scene)
    return split


# -- the rows --------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Row:
    """How one row makes noisy images of clean ones: the captures themselves (neither set), a profile sampled as a
    whole, or a noise effect on the clean image."""

    name: str
    profile: CameraProfile | None = None
    effect: Noise | None = None

    def noisy(self, cleans: Sequence[Tensor], captures: Sequence[Tensor], seed: int, stream: str) -> list[Tensor]:
        """Image ``i`` draws from ``(seed, stream, i)``; simulations rounded to 8 bits."""
        if self.profile is not None:
            return [to_8bit(x) for x in self.profile.simulate(cleans, seed, stream=stream)]
        if self.effect is None:
            return list(captures)
        out = []
        with torch.no_grad():
            for index, clean in enumerate(cleans):
                params = self.effect.make_params((1, *clean.shape), derived_generator(seed, stream, index))
                out.append(to_8bit(self.effect(clean[None], params)[0]))
        return out


def to_8bit(image: Tensor) -> Tensor:
    return (image.clamp(0, 1) * 255).round() / 255


def fit_rows(split: Split, *, oracle: bool = False) -> tuple[dict[str, Row], dict[str, Any]]:
    """Every row, fitted on ``split``'s training pairs (the ``oracle`` row, on its held-out pairs, only when asked
    for), and what was fitted (with the CPU seconds it took)."""
    cpu = time.process_time()
    pairs = PairSet(list(split.train), list(split.train_scenes), [str(i) for i in range(len(split.train))])
    recipe = profile_recipe(len(pairs))
    profile = fit_profile(pairs, recipe, threads=1)
    profile_seconds, cpu = time.process_time() - cpu, time.process_time()
    cleans, captures = split.unit("train")
    stage = Noise.fit(cleans, captures, estimator="residual", seed=0)
    stage_seconds = time.process_time() - cpu
    sums = residual_sums(cleans, captures)
    sigma = sums.pooled_std() / 255.0
    poisson = fit_poisson_gaussian(sums)
    on_held_out = Noise.fit(*split.unit("test"), estimator="residual", seed=0) if oracle else None
    in_chain = [effect for effect in profile.effects if isinstance(effect, Noise)]
    jittered = copy.deepcopy(stage)
    jittered.gain_jitter = level_spread(cleans, captures)
    rows = {
        "real": Row("real"),
        "profile": Row("profile", profile=profile),
        "stage": Row("stage", effect=stage),
        "gaussian": Row("gaussian", effect=Noise(b=sigma**2, linear=False)),
        "poisson_gaussian": Row("poisson_gaussian", effect=poisson),
        "stage_jitter": Row("stage_jitter", effect=jittered),
        **({"oracle": Row("oracle", effect=on_held_out)} if on_held_out is not None else {}),
    }
    fitted = {
        "profile_recipe": recipe.training_dict(),
        "profile_fit_cpu_seconds": round(profile_seconds, 1),
        "profile_quality": profile.quality,
        "profile_noise_sigma_mid_grey": round(in_chain[0].magnitude(), 3) if in_chain else None,
        "stage": stage.extra_repr(),
        "stage_fit_cpu_seconds": round(stage_seconds, 1),
        "stage_sigma_mid_grey": round(stage.magnitude(), 3),
        "stage_jitter_gain_jitter": round(jittered.gain_jitter, 3),
        "oracle_sigma_mid_grey": round(on_held_out.magnitude(), 3) if on_held_out is not None else None,
        "gaussian_sigma_levels": round(sigma * 255, 3),
        "poisson_gaussian": {"a": poisson.a.tolist(), "b": poisson.b.tolist()},
    }
    return rows, fitted


def profile_recipe(pairs: int) -> FitConfig:
    return PROFILE_RECIPE.replace(crops_per_pair=max(8, CROPS_PER_EPOCH // pairs))


def residual_sums(cleans: Sequence[Tensor], captures: Sequence[Tensor]) -> NoiseSums:
    """The real noise ``capture − clean`` on the clean images' flat pixels, binned by clean value."""
    total = NoiseSums.zeros()
    for clean, capture in zip(cleans, captures, strict=True):
        total = total + NoiseSums.measure(capture - clean, clean, flat_mask(clean), clipping=capture)
    return total


def level_spread(cleans: Sequence[Tensor], captures: Sequence[Tensor]) -> float:
    """The std of the log of each capture's own noise level (flat-pixel std of ``capture − clean``)."""
    levels = [residual_sums([clean], [capture]).pooled_std() for clean, capture in zip(cleans, captures, strict=True)]
    logs = torch.tensor([level for level in levels if level > 0]).log()
    return float(logs.std()) if len(logs) > 1 else 0.0


def fit_poisson_gaussian(sums: NoiseSums) -> Noise:
    """Per channel, ``var = a·x + b`` (sRGB values) by least squares on the binned variances, each bin weighted by
    its pixels; ``a`` and ``b`` kept non-negative (a line through the origin, else a constant)."""
    variance = (sums.square / sums.count.clamp_min(1)) / 255.0**2
    x = (torch.arange(BINS, dtype=torch.float64) + 0.5) / BINS
    a, b = torch.zeros(3), torch.zeros(3)
    for channel in range(3):
        weight = sums.count[channel]
        design = torch.stack([x, torch.ones_like(x)], 1) * weight.sqrt()[:, None]
        target = variance[channel] * weight.sqrt()
        slope, offset = torch.linalg.lstsq(design, target[:, None]).solution[:, 0].tolist()
        if offset < 0:
            slope, offset = float((weight * x * variance[channel]).sum() / (weight * x * x).sum()), 0.0
        if slope < 0:
            slope, offset = 0.0, float((weight * variance[channel]).sum() / weight.sum())
        a[channel], b[channel] = slope, offset
    return Noise(a=a, b=b, linear=False)
