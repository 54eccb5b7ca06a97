"""Light and tone: the sRGB transfer function, quantization to a bit depth, and tone curves as 8-bit look-up tables.

Images are float64 arrays in [0, 1] (values may leave it between stages; the encoder clips). References: IEC
61966-2-1 (sRGB transfer function).
"""

from __future__ import annotations

import numpy as np


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """Decode sRGB-encoded values to linear light (IEC 61966-2-1's piecewise curve)."""
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """Encode linear light to sRGB; clips to [0, 1] first (a sensor saturates, nothing is negative)."""
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1.0 / 2.4) - 0.055)


def quantize(x: np.ndarray, bits: int) -> np.ndarray:
    """Round to ``2**bits`` levels over [0, 1] (clipped): an ADC, or an 8-bit buffer between two ISP blocks."""
    top = float(2**bits - 1)
    return np.round(np.clip(x, 0.0, 1.0) * top) / top


def contrast_curve(strength: float) -> np.ndarray:
    """An S-shaped contrast curve sampled at the 256 8-bit codes: ``y = x - s sin(2πx) / 2π`` (slope ``1 + s``
    at mid-grey, ``1 - s`` at the ends; monotone for ``s < 1``)."""
    x = np.arange(256) / 255.0
    return x - strength * np.sin(2.0 * np.pi * x) / (2.0 * np.pi)


def gamma_curve(gamma: float, black: float = 0.0, white: float = 1.0) -> np.ndarray:
    """A power curve with a black lift and a white point, sampled at the 256 8-bit codes: ``black + (white -
    black) x**gamma``."""
    x = np.arange(256) / 255.0
    return black + (white - black) * x**gamma


def lut_8bit(curve: np.ndarray) -> np.ndarray:
    """The 8-bit table of a curve sampled at the 256 codes: its outputs rounded to codes. Where the curve is steeper
    than 1 some output codes are never produced (the skipped levels of a tone curve applied to 8-bit values)."""
    return np.round(np.clip(curve, 0.0, 1.0) * 255.0).astype(np.uint8)


def apply_lut(x: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Apply an 8-bit table to values already on the 8-bit grid (they are rounded to it first)."""
    codes = np.round(np.clip(x, 0.0, 1.0) * 255.0).astype(np.intp)
    return table[codes].astype(np.float64) / 255.0


def apply_curve(x: np.ndarray, curve: np.ndarray) -> np.ndarray:
    """Apply a curve sampled at the 256 codes to float values by linear interpolation (no quantization)."""
    return np.interp(np.clip(x, 0.0, 1.0), np.arange(256) / 255.0, curve)
