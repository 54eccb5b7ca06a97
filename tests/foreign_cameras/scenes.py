"""Clean scenes for the foreign cameras: crops of scikit-image's bundled photos, flat walls (where noise can be
measured) and dead-leaves texture, all 8-bit RGB and drawn from a seed.

scikit-image is imported here only (for its sample photos); the cameras use numpy, scipy and PIL alone.
"""

from __future__ import annotations

from functools import cache

import numpy as np
from PIL import Image

#: Photos bundled with scikit-image (no download); grey ones are tinted so that every channel varies.
PHOTOS = (
    "astronaut",
    "coffee",
    "chelsea",
    "rocket",
    "immunohistochemistry",
    "hubble_deep_field",
    "retina",
    "colorwheel",
    "brick",
    "grass",
    "gravel",
    "camera",
)


@cache
def _photo(name: str) -> np.ndarray:
    import skimage.data

    array = np.asarray(getattr(skimage.data, name)())
    if array.ndim == 2:
        grey = array.astype(np.float64)
        array = np.stack([grey * 0.95 + 8.0, grey, grey * 0.85 + 25.0], axis=-1)
    return np.clip(array[..., :3], 0, 255).astype(np.uint8)


def photo_crop(size: int, rng: np.random.Generator, photos: tuple[str, ...] = PHOTOS) -> np.ndarray:
    """A square crop of a random photo, 50–100 % of its shorter side, area-resized to ``size`` (PIL box), maybe
    mirrored."""
    photo = _photo(photos[int(rng.integers(len(photos)))])
    side = int(min(photo.shape[:2]) * rng.uniform(0.5, 1.0))
    top = int(rng.integers(photo.shape[0] - side + 1))
    left = int(rng.integers(photo.shape[1] - side + 1))
    crop = Image.fromarray(photo[top : top + side, left : left + side]).resize((size, size), Image.Resampling.BOX)
    image = np.asarray(crop)
    return image[:, ::-1].copy() if rng.random() < 0.5 else image


def walls(size: int, rng: np.random.Generator) -> np.ndarray:
    """Flat surfaces: a background and three to five rectangles of uniform colour, over a gradient of at most 4 levels
    across the frame (like a wall, a door and the sky)."""
    image = np.ones((size, size, 3)) * rng.uniform(20.0, 235.0, size=3)
    for _ in range(int(rng.integers(3, 6))):
        top, left = rng.integers(0, size * 3 // 4, size=2)
        height, width = rng.integers(size // 4, size // 2 + 1, size=2)
        image[top : top + height, left : left + width] = rng.uniform(15.0, 240.0, size=3)
    ramp = np.linspace(-2.0, 2.0, size)[None, :, None] * rng.uniform(0.0, 1.0, size=3)
    return np.round(np.clip(image + ramp, 0, 255)).astype(np.uint8)


def dead_leaves(size: int, rng: np.random.Generator, discs: int = 300) -> np.ndarray:
    """Occluding discs of random colour with radii from a power law (r⁻³ between 1.5 and size/4 px): texture at every
    scale with sharp edges, the statistics of natural images' edges."""
    yy, xx = np.mgrid[0:size, 0:size] + 0.5
    image = np.ones((size, size, 3)) * rng.uniform(0.0, 255.0, size=3)
    low, high = 1.5, size / 4.0
    for _ in range(discs):
        u = rng.random()
        radius = (low**-2 - u * (low**-2 - high**-2)) ** -0.5
        cy, cx = rng.uniform(-radius, size + radius, size=2)
        inside = (yy - cy) ** 2 + (xx - cx) ** 2 <= radius**2
        image[inside] = rng.uniform(0.0, 255.0, size=3)
    return np.round(image).astype(np.uint8)


def scenes(count: int, size: int, seed: int, photos: tuple[str, ...] = PHOTOS) -> list[np.ndarray]:
    """``count`` clean 8-bit images ``(size, size, 3)``: of every four, two photo crops, one set of flat walls and one
    dead-leaves texture. The same seed gives the same images."""
    rng = np.random.default_rng(seed)
    images = []
    for index in range(count):
        kind = index % 4
        if kind == 1:
            images.append(walls(size, rng))
        elif kind == 3:
            images.append(dead_leaves(size, rng))
        else:
            images.append(photo_crop(size, rng, photos))
    return images
