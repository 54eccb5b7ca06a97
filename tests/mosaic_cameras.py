"""Cameras for the mosaic-form checks (tests/test_mosaic_form.py, experiments/mosaic_form_null.py), written with
numpy, scipy, OpenCV and PIL, none of them in the foreign bench: a JPEG of PIL, a sample-aligned 2× bilinear upscale
(a strong phase pattern every channel shares) and a BGGR Bayer camera demosaiced by OpenCV."""

from __future__ import annotations

import io

import cv2
import numpy as np
from PIL import Image
from scipy import ndimage


def jpeg(image: np.ndarray, quality: int) -> np.ndarray:
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="JPEG", quality=quality, subsampling=2)
    return np.asarray(Image.open(io.BytesIO(buffer.getvalue())).convert("RGB"))


def aligned_upscale(image: np.ndarray) -> np.ndarray:
    """Every second row and column of ``image`` kept, the others the mean of their two neighbours (a 2× bilinear
    upscale whose output grid holds the input's samples)."""
    small = image[::2, ::2].astype(np.float64)
    rows = np.repeat(small, 2, axis=0)
    rows[1::2] = (small + np.roll(small, -1, axis=0)) / 2
    both = np.repeat(rows, 2, axis=1)
    both[:, 1::2] = (rows + np.roll(rows, -1, axis=1)) / 2
    return np.round(both).clip(0, 255).astype(np.uint8)


def _linear(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def _encoded(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


#: The BGGR camera's filter overlap and sensitivities (red and blue less sensitive than green).
_MIX = np.array([[0.8, 0.15, 0.05], [0.1, 0.8, 0.1], [0.03, 0.2, 0.77]])
_GAINS = np.array([0.55, 1.0, 0.7])


def bggr_camera(image: np.ndarray, seed: tuple[int, int]) -> np.ndarray:
    """A Bayer camera not in the foreign bench: linear light, Gaussian lens σ 0.6, filter overlap, BGGR sites,
    Poisson-Gaussian noise (1,800 e⁻, read 0.2 %), white balance on the mosaic, OpenCV's edge-aware demosaic of the
    16-bit plane, the inverse overlap, sRGB, 8 bits, PIL JPEG 88 with 4:2:0 chroma."""
    rng = np.random.default_rng(seed)
    x = ndimage.gaussian_filter(_linear(image / 255.0), (0.6, 0.6, 0), mode="mirror")
    x = (x @ _MIX.T) * _GAINS
    plane = np.zeros(x.shape[:2])
    for row, column, colour in ((0, 0, 2), (0, 1, 1), (1, 0, 1), (1, 1, 0)):
        plane[row::2, column::2] = x[row::2, column::2, colour] / _GAINS[colour]
    plane = rng.poisson(np.clip(plane * _GAINS.mean(), 0, None) * 1800) / 1800 / _GAINS.mean()
    plane = plane + rng.normal(0, 0.002, plane.shape)
    raw = np.round(np.clip(plane, 0, 1) * 65535).astype(np.uint16)
    # OpenCV names a layout by its second row's first two sites: BGGR is its "RG".
    rgb = cv2.cvtColor(raw, cv2.COLOR_BayerRG2RGB_EA).astype(np.float64) / 65535
    return jpeg(np.round(_encoded(rgb @ np.linalg.inv(_MIX).T) * 255).astype(np.uint8), 88)
