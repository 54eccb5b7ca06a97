"""``distill_profile``: a faster profile from a fitted one, with no pairs: a narrower network is trained to give what
the profile's network gives on clean images (knowledge distillation), and the effect stages are copied as they are.

Steps: clean images (a folder, tensors, or generated dead-leaves images) → split by image into training and
validation → the teacher network's float32 output on each →
:func:`~camdegrade.fitting.network.training.fit_network` of a network of ``width`` on (clean, teacher output) with
the given recipe → a :class:`CameraProfile` with the
student network and copies of the teacher's effect stages, whose metadata records how it was made and how close
the student came to the teacher on the validation images.

References:
    G. Hinton, O. Vinyals, J. Dean, "Distilling the Knowledge in a Neural Network", NIPS Deep Learning Workshop,
    2014 (here on the regression outputs).
"""

from __future__ import annotations

import copy
import math
import os
import platform
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from camdegrade._runtime.threads import torch_threads
from camdegrade._support.pixels import as_unit
from camdegrade._support.seeds import derived_generator
from camdegrade._version import __version__
from camdegrade.effects.base import evenly_spaced
from camdegrade.fitting.network.training import EpochResult, fit_network
from camdegrade.fitting.recipe import FitConfig, resolve_recipe
from camdegrade.fitting.record import record_quality
from camdegrade.functional.optics.geometry import shrink_to_max_side
from camdegrade.measures.metrics import psnr
from camdegrade.network.inference import run_network
from camdegrade.pairs.folder import read_folder
from camdegrade.pairs.pairset import ImagePair
from camdegrade.profile import CameraProfile, as_profile
from camdegrade.synthetic import dead_leaves_images

__all__ = [
    "DEFAULT_WIDTH",
    "MAX_IMAGES",
    "MAX_SIDE",
    "SYNTHETIC_IMAGES",
    "SYNTHETIC_SIZE",
    "Log",
    "distill_profile",
    "student_warnings",
]

Log = Callable[[str], None]
#: Images a distillation generates when it is given none (dead leaves, 256²).
SYNTHETIC_IMAGES = 64
SYNTHETIC_SIZE = 256
#: The student's width unless told: about a quarter of the paper network's arithmetic.
DEFAULT_WIDTH = 32
#: At most this many of the given images are used (evenly spaced), each at most this many pixels a side (larger
#: ones are downscaled): every image is kept in memory with the teacher's float32 output beside it.
MAX_IMAGES = 256
MAX_SIDE = 1024


def distill_profile(
    profile: CameraProfile | str | os.PathLike[str],
    images: str | os.PathLike[str] | Sequence[Tensor] | None = None,
    *,
    width: int | None = None,
    recipe: str | FitConfig = "fast",
    epochs: int | None = None,
    seed: int | None = None,
    device: torch.device | str = "cpu",
    threads: int | None = None,
    progress: bool = False,
    callback: Callable[[EpochResult], None] | None = None,
    name: str | None = None,
    log: Log | None = None,
) -> CameraProfile:
    """A profile whose network of ``width`` (32: about a quarter of the paper's arithmetic) is trained to give what
    ``profile``'s network gives, with ``profile``'s effect stages copied. Images larger than :data:`MAX_SIDE` are
    downscaled and at most :data:`MAX_IMAGES` are used (each is kept in memory with the teacher's output).

    Args:
        profile: the teacher: a :class:`CameraProfile`, a built-in name or a path; it must have a network.
        images: clean images like those the profile will degrade: a folder (read recursively; files that cannot
            be read are skipped and logged), or ``(3, H, W)`` tensors (uint8, or float in [0, 1]). ``None``:
            :data:`SYNTHETIC_IMAGES` generated dead-leaves images (:mod:`camdegrade.synthetic`).
        width: the student network's width (its architecture is the recipe's ``arch``); ``None``: 32, or a
            :class:`FitConfig` recipe's own.
        recipe, epochs: the training recipe (:class:`FitConfig` or a name of its recipes) and its epochs; the
            recipe's ``val_fraction`` is the share of the images (at least one) that choose the best epoch and give
            the reported PSNR (its ``effects`` do not apply: the teacher's stages are copied).
        seed: the split, the generated images, the student's initialisation and crops (``None``: the recipe's).

    Returns:
        The profile; ``fitted`` records the teacher, the images, the recipe and the best epoch, ``quality`` the
        student's PSNR against the teacher's network on the validation images and that of the clean images
        unchanged; a student further from its teacher than the clean images are gets ``fitted['warnings']`` (also
        logged; see :func:`student_warnings`).
    """
    say = log or (lambda message: None)
    teacher = as_profile(profile)
    if teacher.network is None:
        raise ValueError(f"profile {teacher.name!r} has no network to distil (it holds effect stages only)")
    if width is None and not isinstance(recipe, FitConfig):
        width = DEFAULT_WIDTH
    config = resolve_recipe(recipe).replace(epochs=epochs, width=width, seed=seed)
    width, seed = config.width, config.seed
    if config.val_fraction == 0:
        raise ValueError("val_fraction must be in (0, 1) for a distillation (it validates on its images), got 0")
    with torch_threads(threads):
        cleans, source = _clean_images(images, config.crop, seed, say)
        train, val = _split(cleans, config.val_fraction, seed)
        say(f"distilling {teacher.name or 'the profile'} into width {width} on {len(train)} images of {source}")
        started = time.perf_counter()
        pairs = [(image, _teacher_output(teacher, image)) for image in cleans]
        student, history = fit_network(
            [pairs[i] for i in train],
            [pairs[i] for i in val],
            config,
            device=device,
            progress=progress,
            callback=callback,
        )
        minutes = (time.perf_counter() - started) / 60
    fast = CameraProfile(
        student,
        [copy.deepcopy(effect) for effect in teacher.effects],
        name=name if name is not None else f"{teacher.name}-fast" if teacher.name else "",
        description=f"{teacher.description} (network distilled to width {width})".strip(),
    )
    fast.fitted = _record(teacher, source, len(train), len(val), config, history, minutes)
    quality = _quality(student, [pairs[i] for i in val])
    record_quality(fast, quality, student_warnings(quality), say)
    return fast


def _clean_images(
    images: str | os.PathLike[str] | Sequence[Tensor] | None, crop: int, seed: int, say: Log
) -> tuple[list[Tensor], str]:
    """The clean images as ``(3, H, W)`` tensors at least ``crop`` a side, and a description of where they came
    from; files that cannot be read and images smaller than ``crop`` are left out and logged."""
    if images is None:
        return dead_leaves_images(SYNTHETIC_IMAGES, SYNTHETIC_SIZE, seed=seed), "generated dead leaves"
    if isinstance(images, (str, os.PathLike)):
        loaded, source = _read_folder(Path(images), say), f"folder {os.fspath(images)!r}"
    else:
        loaded, source = list(images), "the given images"
    for index, image in enumerate(loaded):
        if not isinstance(image, Tensor) or image.ndim != 3 or image.shape[0] != 3:
            shape = tuple(image.shape) if isinstance(image, Tensor) else type(image).__name__
            raise ValueError(f"images[{index}] must be a (3, H, W) tensor, got {shape}")
    usable = [shrink_to_max_side(image, MAX_SIDE) for image in evenly_spaced(loaded, MAX_IMAGES)]
    if len(loaded) > MAX_IMAGES:
        say(f"using {MAX_IMAGES} of the {len(loaded)} images (evenly spaced)")
    usable = [image for image in usable if min(image.shape[-2:]) >= crop]
    if len(usable) < min(len(loaded), MAX_IMAGES):
        say(f"left out {min(len(loaded), MAX_IMAGES) - len(usable)} image(s) smaller than the {crop}-pixel crop")
    if len(usable) < 2:
        raise ValueError(
            f"distillation needs at least 2 images of at least {crop}² pixels from {source}, got {len(usable)}"
        )
    return usable, source


def _read_folder(folder: Path, say: Log) -> list[Tensor]:
    if not folder.is_dir():
        raise NotADirectoryError(f"images must be a folder of images, got {str(folder)!r}")
    found = read_folder(folder)
    for item in found.skipped:
        say(f"skipped {item.path}: {item.detail}")
    return found.images


def _split(images: Sequence[Tensor], val_fraction: float, seed: int) -> tuple[list[int], list[int]]:
    """``(train, validation)`` indices: a seeded share ``val_fraction`` of the images (at least one) validates."""
    if not 0.0 < val_fraction < 1.0:
        raise ValueError(f"val_fraction must be in (0, 1), got val_fraction={val_fraction!r}")
    order = torch.randperm(len(images), generator=derived_generator(seed, "distill-split")).tolist()
    held = max(1, math.ceil(val_fraction * len(images)))
    return sorted(order[held:]), sorted(order[:held])


def _teacher_output(teacher: CameraProfile, image: Tensor) -> Tensor:
    """The teacher network's float32 output on one image (exact arithmetic: it is the student's target)."""
    assert teacher.network is not None
    with torch.no_grad():
        return run_network(teacher.network, as_unit(image)[None], "float32")[0]


def _record(
    teacher: CameraProfile,
    source: str,
    train: int,
    val: int,
    config: FitConfig,
    history: Sequence[EpochResult],
    minutes: float,
) -> dict[str, Any]:
    best = max(history, key=lambda result: result.val_psnr)
    return {
        "distilled_from": teacher.name,
        "teacher_width": teacher.network.width if teacher.network is not None else None,
        "teacher_fitted": teacher.fitted,
        "images": source,
        "train_images": train,
        "validation_images": val,
        "recipe": config.training_dict(),
        "best_epoch": best.epoch,
        "fit_minutes": round(minutes, 2),
        "machine": f"{platform.machine()}, {torch.get_num_threads()} threads, torch {torch.__version__}",
        "camdegrade": __version__,
    }


def _quality(student: torch.nn.Module, val: Sequence[ImagePair]) -> dict[str, Any]:
    """The student's PSNR against the teacher's output on the validation images, and the clean images' (the
    identity's)."""
    with torch.no_grad():
        scores = [psnr(run_network(student, as_unit(clean)[None], "float32")[0], target) for clean, target in val]
    identity = [psnr(as_unit(clean), target) for clean, target in val]
    return {
        "validation_images": len(val),
        "student_vs_teacher_psnr_db": round(sum(scores) / len(scores), 3),
        "identity_vs_teacher_psnr_db": round(sum(identity) / len(identity), 3),
    }


def student_warnings(quality: dict[str, Any]) -> list[str]:
    """What a distillation's validation scores say is wrong: a student further from its teacher's output than the
    clean images themselves (too few epochs or images)."""
    student, identity = quality["student_vs_teacher_psnr_db"], quality["identity_vs_teacher_psnr_db"]
    if not student < identity:
        return []
    return [
        f"the student is far from its teacher on the validation images ({student:.2f} dB, less than the clean images' "
        f"{identity:.2f} dB): distil for more epochs (--epochs) or on more images"
    ]
