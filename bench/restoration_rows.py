"""The data and the rows of the restoration-transfer bench (``bench_restoration_transfer.py``): the City100 iPhone X
pairs split as the built-in was fitted (training scenes 001–055, held-out 056–070 and 098), and what each row gives
the restorer as its degraded input for the training scenes' clean images:

- ``real``: the iPhone's own captures of the training scenes;
- ``built_in``: the built-in ``city100-iphonex`` (fitted on the pairs of 001–055) on their clean images, seeded;
- ``colour_map``: a Gaussian blur and an affine colour map (3×3 matrix + offset), both fitted by least squares on
  the training pairs (:func:`fit_colour_map`), the baseline the closure is measured from;
- ``unpaired``: the profile :func:`camdegrade.fitting.unpaired.fit_unpaired` fits on its own split (clean images of
  001–035, captures of 036–055: no pair), seeded;
- ``clean``: the clean image itself (no degradation: the restorer learns the identity, a floor).

Every simulated image is rounded to 8 bits, as a saved training set would be.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade import load_profile
from camdegrade._support.pixels import as_unit, unit_to_bytes
from camdegrade.effects import Blur
from camdegrade.errors import PairsError
from camdegrade.fitting.unpaired import fit_unpaired
from camdegrade.pairs import discover_pairs, filter_pairs, load_pair
from camdegrade.profile import CameraProfile

SUBSET = "city100_iPhoneX"
TRAINING = tuple(f"{n:03d}" for n in range(1, 56))
HELD_OUT = (*(f"{n:03d}" for n in range(56, 71)), "098")
#: The unpaired profile's split of the training scenes: clean images of the first, captures of the second.
UNPAIRED_CLEAN, UNPAIRED_CAPTURED = TRAINING[:35], TRAINING[35:]
ROWS = ("real", "built_in", "colour_map", "unpaired", "clean")
BUILT_IN = "city100-iphonex"
#: The colour map is fitted on pixels averaged over POOL × POOL blocks: averaging removes the noise and the small
#: misregistration, which a colour map cannot explain.
POOL = 4


# -- data ------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class City100:
    """Clean images and captures (float ``(3, H, W)`` in [0, 1]) of the training and held-out scenes."""

    train_clean: list[Tensor]
    train_captured: list[Tensor]
    test_clean: list[Tensor]
    test_captured: list[Tensor]
    train_scenes: tuple[str, ...] = TRAINING
    test_scenes: tuple[str, ...] = HELD_OUT


def _listed(root: Path) -> dict:
    return {pair.scene: pair for pair in filter_pairs(discover_pairs(root / "pairs.csv").pairs, subset=SUBSET)}


def missing_scenes(root: Path) -> list[str]:
    """The scenes of :data:`TRAINING` and :data:`HELD_OUT` that ``root/pairs.csv`` does not list (all of them when
    it lists no usable pair)."""
    try:
        listed = _listed(root)
    except PairsError:
        listed = {}
    return sorted(set(TRAINING + HELD_OUT) - set(listed))


@cache
def load_city100(root: Path, held_out: tuple[str, ...] = HELD_OUT) -> City100:
    """The pairs of ``root/pairs.csv`` (read once per process); ``held_out`` may be a part of :data:`HELD_OUT`."""
    found = _listed(root)
    missing = sorted(set(TRAINING + held_out) - set(found))
    if missing:
        raise FileNotFoundError(f"{root / 'pairs.csv'} lacks the {SUBSET} scenes {', '.join(missing)}")
    train = [tuple(as_unit(image) for image in load_pair(found[scene])) for scene in TRAINING]
    test = [tuple(as_unit(image) for image in load_pair(found[scene])) for scene in held_out]
    return City100(
        [c for c, _ in train], [x for _, x in train], [c for c, _ in test], [x for _, x in test], TRAINING, held_out
    )


def stored(image: Tensor) -> Tensor:
    """``image`` as an 8-bit file would hold it, back in [0, 1]."""
    return as_unit(unit_to_bytes(image.clamp(0, 1)))


# -- the blur + colour map -------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ColourMap:
    """A Gaussian blur of ``sigma`` pixels (in linear light, as :class:`~camdegrade.effects.Blur` blurs), then
    ``matrix[:, :3] @ rgb + matrix[:, 3]`` on the sRGB values."""

    sigma: float
    matrix: Tensor

    def __call__(self, clean: Tensor) -> Tensor:
        with torch.no_grad():
            blurred = Blur(self.sigma)(clean[None])[0]
        mapped = torch.einsum("ij,jhw->ihw", self.matrix[:, :3], blurred) + self.matrix[:, 3, None, None]
        return mapped.clamp(0, 1)


def fit_colour_map(cleans: Sequence[Tensor], captures: Sequence[Tensor]) -> ColourMap:
    """:meth:`Blur.fit` of the clean images to the captures (isotropic, with a per-pair colour map projected out),
    then the ``(3, 4)`` affine map from the blurred clean image to the capture by least squares on
    :data:`POOL`-averaged pixels."""
    sigma = float(Blur.fit(list(cleans), list(captures)).sigma_x)
    inputs, targets = [], []
    with torch.no_grad():
        for clean, capture in zip(cleans, captures, strict=True):
            blurred = F.avg_pool2d(Blur(sigma)(clean[None]), POOL)[0].reshape(3, -1).T.double()
            inputs.append(torch.cat([blurred, torch.ones(len(blurred), 1, dtype=torch.float64)], 1))
            targets.append(F.avg_pool2d(capture[None], POOL)[0].reshape(3, -1).T.double())
    solution = torch.linalg.lstsq(torch.cat(inputs), torch.cat(targets)).solution  # (4, 3)
    return ColourMap(sigma, solution.T.float())


# -- the rows --------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Row:
    """How one row degrades clean images: the captures themselves (``source="captured"``), the clean images
    (``"clean"``), a profile sampled, or the blur + colour map."""

    name: str
    source: str = "simulated"
    profile: CameraProfile | None = None
    colour_map: ColourMap | None = None

    def degraded(self, cleans: Sequence[Tensor], captures: Sequence[Tensor], seed: int, stream: str) -> list[Tensor]:
        """Image ``i`` of a profile draws from ``(seed, stream, i)``; simulations rounded to 8 bits."""
        if self.source == "captured":
            return list(captures)
        if self.source == "clean":
            return list(cleans)
        if self.profile is not None:
            return self.profile.simulate(cleans, seed, stream=stream, eight_bit=True)
        if self.colour_map is None:
            raise ValueError(f"row {self.name!r} has neither a profile nor a colour map")
        return [stored(self.colour_map(clean)) for clean in cleans]


def unpaired_profile(root: Path, path: Path, log=print) -> CameraProfile:
    """The unpaired profile saved at ``path``; fitted on its split (and saved there) when the file is absent."""
    if path.is_file():
        return load_profile(path)
    data = load_city100(root)
    by_scene = dict(zip(data.train_scenes, zip(data.train_clean, data.train_captured, strict=True), strict=True))
    started = time.perf_counter()
    profile = fit_unpaired(
        [by_scene[scene][1] for scene in UNPAIRED_CAPTURED],
        [by_scene[scene][0] for scene in UNPAIRED_CLEAN],
        seed=0,
        name="city100-iphonex-unpaired",
        description="City100 iPhone X fitted unpaired: clean 001-035, captures 036-055",
        log=log,
    )
    log(f"unpaired profile fitted in {time.perf_counter() - started:.0f} s; saved to {path}")
    path.parent.mkdir(parents=True, exist_ok=True)
    profile.save(path)
    return profile


def make_rows(
    root: Path, names: Sequence[str], unpaired_path: Path, built_in: str | Path = BUILT_IN
) -> tuple[dict[str, Row], dict[str, object]]:
    """The rows ``names``, fitted on the training scenes (``built_in``: the built-in row's profile, a name or a
    file), and what was fitted (with the CPU seconds)."""
    cpu = time.process_time()
    data = load_city100(root)
    colour_map = fit_colour_map(data.train_clean, data.train_captured)
    fitted: dict[str, object] = {
        "colour_map_sigma": round(colour_map.sigma, 3),
        "colour_map": [[round(v, 4) for v in row] for row in colour_map.matrix.tolist()],
        "colour_map_fit_cpu_seconds": round(time.process_time() - cpu, 1),
        "built_in_profile": str(built_in),
    }
    rows = {
        "real": Row("real", source="captured"),
        "built_in": Row("built_in", profile=load_profile(built_in)),
        "colour_map": Row("colour_map", colour_map=colour_map),
        "clean": Row("clean", source="clean"),
    }
    if "unpaired" in names:
        rows["unpaired"] = Row("unpaired", profile=unpaired_profile(root, unpaired_path))
        fitted["unpaired_profile"] = str(unpaired_path)
    return {name: rows[name] for name in names}, fitted
