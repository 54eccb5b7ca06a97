"""Demosaicing a Bayer plane: bilinear interpolation, and an edge-directed one (Hamilton-Adams green, then the
colour differences interpolated over the full green).

References: Hamilton & Adams, "Adaptive color plan interpolation in single sensor color electronic camera",
US patent 5,629,734 (1997); Gunturk et al., "Demosaicking: color filter array interpolation", IEEE Signal
Processing Magazine 2005 (the colour-difference rule).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from foreign_cameras.sensor import bayer_masks

#: Weights of the neighbours a bilinear demosaicer averages (the centre included, for the normalised convolution).
_BILINEAR = np.array([[0.25, 0.5, 0.25], [0.5, 1.0, 0.5], [0.25, 0.5, 0.25]])


def _interpolate(values: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Normalised convolution: the weighted mean of the known neighbours (3×3 bilinear weights), the known values
    kept. The border is mirrored whole-sample, which keeps the Bayer phase."""
    weights = ndimage.convolve(known.astype(np.float64), _BILINEAR, mode="mirror")
    summed = ndimage.convolve(np.where(known, values, 0.0), _BILINEAR, mode="mirror")
    return np.where(known, values, summed / np.maximum(weights, 1e-12))


def bilinear(plane: np.ndarray, pattern: str) -> np.ndarray:
    """(H, W, 3) from a Bayer plane: each colour bilinearly interpolated from its own sites."""
    masks = bayer_masks(*plane.shape, pattern)
    return np.stack([_interpolate(plane, masks[..., c]) for c in range(3)], axis=-1)


def _shifted(plane: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """``plane[y + dy, x + dx]`` at every site, the border mirrored whole-sample."""
    padded = np.pad(plane, 2, mode="reflect")
    height, width = plane.shape
    return padded[2 + dy : 2 + dy + height, 2 + dx : 2 + dx + width]


def hamilton_adams_green(plane: np.ndarray, green: np.ndarray) -> np.ndarray:
    """The full green plane: at red and blue sites, interpolated along the direction of the smaller gradient (the
    green difference plus the second difference of the site's own colour), with the second difference as a
    correction; both directions averaged where they are equal."""
    left, right = _shifted(plane, 0, -1), _shifted(plane, 0, 1)
    up, down = _shifted(plane, -1, 0), _shifted(plane, 1, 0)
    second_h = 2.0 * plane - _shifted(plane, 0, -2) - _shifted(plane, 0, 2)
    second_v = 2.0 * plane - _shifted(plane, -2, 0) - _shifted(plane, 2, 0)
    gradient_h = np.abs(left - right) + np.abs(second_h)
    gradient_v = np.abs(up - down) + np.abs(second_v)
    along_h = (left + right) / 2.0 + second_h / 4.0
    along_v = (up + down) / 2.0 + second_v / 4.0
    chosen = np.where(gradient_h < gradient_v, along_h, np.where(gradient_v < gradient_h, along_v, 0.0))
    chosen = np.where(gradient_h == gradient_v, (along_h + along_v) / 2.0, chosen)
    return np.where(green, plane, chosen)


def hamilton_adams(plane: np.ndarray, pattern: str) -> np.ndarray:
    """(H, W, 3) from a Bayer plane: Hamilton-Adams green, then red and blue as the green plus their colour
    difference (red − green, blue − green) bilinearly interpolated from their own sites."""
    masks = bayer_masks(*plane.shape, pattern)
    green = hamilton_adams_green(plane, masks[..., 1])
    red = green + _interpolate(plane - green, masks[..., 0])
    blue = green + _interpolate(plane - green, masks[..., 2])
    return np.stack([red, green, blue], axis=-1)


DEMOSAICERS = {"bilinear": bilinear, "hamilton_adams": hamilton_adams}
