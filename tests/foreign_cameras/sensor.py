"""The sensor and its sampling: PIL's resamplers (a sensor with fewer pixels, an ISP's digital zoom), the Bayer
colour filter array, and noise (Poisson-Gaussian in linear raw, white read-out noise, row noise).

References: Foi et al., "Practical Poissonian-Gaussian noise modeling and fitting for single-image raw-data",
IEEE TIP 2008; Bayer, US patent 3,971,065 (1976).
"""

from __future__ import annotations

import numpy as np
from PIL import Image

#: PIL's resamplers by name. PIL widens the kernel by the reduction factor when it downsamples (antialiased),
#: except ``nearest``, which aliases.
RESAMPLERS: dict[str, Image.Resampling] = {
    "nearest": Image.Resampling.NEAREST,
    "bilinear": Image.Resampling.BILINEAR,
    "bicubic": Image.Resampling.BICUBIC,
    "lanczos": Image.Resampling.LANCZOS,
    "box": Image.Resampling.BOX,
}

#: Bayer layouts: the colour (0 red, 1 green, 2 blue) of the sites (0, 0), (0, 1), (1, 0), (1, 1).
BAYER: dict[str, tuple[int, int, int, int]] = {
    "RGGB": (0, 1, 1, 2),
    "GRBG": (1, 0, 2, 1),
    "GBRG": (1, 2, 0, 1),
    "BGGR": (2, 1, 1, 0),
}


def resize(x: np.ndarray, size: tuple[int, int], method: str) -> np.ndarray:
    """``x`` (H, W, C) resized to ``size`` = (height, width) by a PIL resampler, each channel a 32-bit float image
    (no rounding to 8 bits: that is a stage of its own)."""
    if method not in RESAMPLERS:
        raise ValueError(f"method must be one of {sorted(RESAMPLERS)}, got method={method!r}")
    height, width = size
    planes = [
        np.asarray(Image.fromarray(x[..., c].astype(np.float32)).resize((width, height), RESAMPLERS[method]))
        for c in range(x.shape[-1])
    ]
    return np.stack(planes, axis=-1).astype(np.float64)


def resize_8bit(x: np.ndarray, size: tuple[int, int], method: str) -> np.ndarray:
    """``x`` rounded to 8 bits and resized as an RGB image by PIL (what an ISP working in 8-bit buffers does:
    PIL rounds its output to 8 bits again)."""
    height, width = size
    image = Image.fromarray(np.round(np.clip(x, 0.0, 1.0) * 255.0).astype(np.uint8))
    return np.asarray(image.resize((width, height), RESAMPLERS[method]), dtype=np.float64) / 255.0


def bayer_masks(height: int, width: int, pattern: str) -> np.ndarray:
    """Boolean (H, W, 3): which colour each site of the colour filter array samples."""
    if pattern not in BAYER:
        raise ValueError(f"pattern must be one of {sorted(BAYER)}, got pattern={pattern!r}")
    colours = np.array(BAYER[pattern]).reshape(2, 2)
    tiled = np.tile(colours, ((height + 1) // 2, (width + 1) // 2))[:height, :width]
    return tiled[..., None] == np.arange(3)


def mosaic(x: np.ndarray, pattern: str) -> np.ndarray:
    """The single plane (H, W) a Bayer sensor records of the linear image ``x`` (H, W, 3)."""
    masks = bayer_masks(*x.shape[:2], pattern)
    return (x * masks).sum(axis=-1)


def poisson_gaussian(x: np.ndarray, full_well: float, read_std: float, rng: np.random.Generator) -> np.ndarray:
    """Shot noise and read noise of linear raw values ``x`` (1 = ``full_well`` electrons): Poisson counts of
    ``x · full_well`` electrons plus Gaussian read noise of ``read_std`` (in units of full scale)."""
    electrons = rng.poisson(np.clip(x, 0.0, None) * full_well)
    return electrons / full_well + rng.normal(0.0, read_std, size=x.shape)


def white_noise(x: np.ndarray, std: float, rng: np.random.Generator) -> np.ndarray:
    """Independent Gaussian noise of ``std`` (units of full scale) on every value."""
    return x + rng.normal(0.0, std, size=x.shape)


def row_noise(x: np.ndarray, std: float, rng: np.random.Generator) -> np.ndarray:
    """A Gaussian offset of ``std`` per row, the same on every channel: read-out stripes of a rolling shutter."""
    offsets = rng.normal(0.0, std, size=(x.shape[0],) + (1,) * (x.ndim - 1))
    return x + offsets
