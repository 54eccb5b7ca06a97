"""Random crops of the colour photographs that ship inside scikit-image (no download), for the examples that build
virtual-camera pairs: training and held-out photographs never overlap."""

from __future__ import annotations

import numpy as np
import torch
from skimage import data as skdata

#: Training photographs (``colorwheel``: saturated hues no photograph here has) and held-out ones.
TRAIN_PHOTOS = (
    "astronaut",
    "rocket",
    "immunohistochemistry",
    "retina",
    "hubble_deep_field",
    "motorcycle",
    "colorwheel",
)
HELD_OUT_PHOTOS = ("chelsea", "coffee")


def photo(name: str) -> np.ndarray:
    """The scikit-image photograph ``name`` as ``(H, W, 3)`` uint8."""
    if name == "motorcycle":
        return skdata.stereo_motorcycle()[0]
    return getattr(skdata, name)()[..., :3]


def random_crops(image: np.ndarray, count: int, size: int, rng: np.random.Generator) -> list[torch.Tensor]:
    """``count`` random square crops of ``image`` covering 50–100 % of its short side, resized to ``size``²,
    randomly flipped; as uint8 ``(3, size, size)`` tensors."""
    tensor = torch.from_numpy(np.ascontiguousarray(image[..., :3])).permute(2, 0, 1).float()
    height, width = tensor.shape[-2:]
    crops = []
    for _ in range(count):
        side = int(rng.integers(max(size // 2, min(height, width) // 2), min(height, width) + 1))
        top, left = int(rng.integers(0, height - side + 1)), int(rng.integers(0, width - side + 1))
        crop = tensor[:, top : top + side, left : left + side][None]
        crop = torch.nn.functional.interpolate(crop, size=(size, size), mode="bilinear", antialias=True)[0]
        if rng.random() < 0.5:
            crop = crop.flip(-1)
        crops.append(crop.round().clamp(0, 255).to(torch.uint8))
    return crops


def photo_crops(names: tuple[str, ...], per_photo: int, size: int, seed: int) -> list[torch.Tensor]:
    """``per_photo`` random crops of each photograph of ``names`` (seeded)."""
    rng = np.random.default_rng(seed)
    return [crop for name in names for crop in random_crops(photo(name), per_photo, size, rng)]
