"""Kernel of a sensor with fewer pixels than the image it outputs: sampled at a fraction of the resolution, then
upsampled back by the ISP.

The sampling low-passes (``antialiased``: a bilinear reduction that filters out what the sensor's grid cannot hold;
``area``: each sensor pixel the mean of the output pixels it covers, as a sensor's pixel integrates the light on
its area, so that detail above the sensor's Nyquist frequency aliases as it does in a camera without an optical
low-pass filter) and the upsampling leaves the images of the sampled
spectrum above its Nyquist frequency, a pattern locked to the sensor's grid (period ``1 / scale`` pixels) that no
shift-invariant filter, and so no convolutional network by itself, reproduces.

References:
    R. Keys, "Cubic convolution interpolation for digital image processing", IEEE TASSP 29(6), 1981 (the bicubic
    upsampler); R. C. Gonzalez, R. E. Woods, "Digital Image Processing", 4th ed., 2018, ch. 4 (sampling, aliasing
    and the spectrum of an interpolated image).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from camdegrade.functional._utils import apply_float, check_image
from camdegrade.functional.sensor.resampling import resample_matrix

__all__ = ["SAMPLERS", "UPSAMPLERS", "resolution_image", "sensor_size"]

#: How the ISP brings the sensor's samples back to the output size: ``bicubic`` (Keys, a = −0.75) and ``bilinear``
#: by ``torch.nn.functional.interpolate``, the others by :mod:`camdegrade.functional.sensor.resampling`
#: (``catmull_rom``: Keys with a = −0.5, PIL's and OpenCV's bicubic; ``lanczos``: 3 lobes; ``box`` and ``nearest``:
#: pixel replication, alike at integer factors).
UPSAMPLERS: tuple[str, ...] = ("bicubic", "bilinear", "catmull_rom", "lanczos", "box", "nearest")
#: How the sensor samples the image: ``antialiased`` (bilinear, antialiased: no aliasing) or ``area`` (the mean over
#: each sensor pixel's area: aliasing as a sensor's).
SAMPLERS: tuple[str, ...] = ("antialiased", "area")


def sensor_size(height: int, width: int, scale: float) -> tuple[int, int]:
    """The sensor's ``(rows, columns)`` for an output of ``height × width`` at ``scale`` (at least one of each)."""
    return max(1, round(height * scale)), max(1, round(width * scale))


def resolution_image(
    image: torch.Tensor, scale: float, upsample: str = "bicubic", sample: str = "antialiased"
) -> torch.Tensor:
    """``up(down(x))``: ``image`` reduced to ``scale`` of its size (``sample``) and upsampled back (``upsample``),
    clipped to [0, 1]; ``scale`` 1 is the identity.

    Args:
        image: ``[..., 3, H, W]`` uint8 or float in [0, 1].
        scale: the sensor's resolution relative to the output, in (0, 1].
        upsample: one of :data:`UPSAMPLERS` (the ISP's resampling kernel).
        sample: one of :data:`SAMPLERS` (how the sensor samples).

    Examples:
        >>> image = torch.rand(1, 3, 16, 16, generator=torch.Generator().manual_seed(0))
        >>> torch.equal(resolution_image(image, 1.0), image)
        True
        >>> resolution_image(image, 0.5).shape
        torch.Size([1, 3, 16, 16])
    """
    check_image(image)
    if not 0.0 < float(scale) <= 1.0:
        raise ValueError(f"scale must be in (0, 1], got scale={scale!r}")
    if upsample not in UPSAMPLERS:
        raise ValueError(f"upsample must be one of {UPSAMPLERS}, got upsample={upsample!r}")
    if sample not in SAMPLERS:
        raise ValueError(f"sample must be one of {SAMPLERS}, got sample={sample!r}")
    height, width = image.shape[-2:]
    low = sensor_size(height, width, float(scale))
    if low == (height, width):
        return image.clone()

    def kernel(x: torch.Tensor) -> torch.Tensor:
        flat = x.reshape(-1, *x.shape[-3:])
        if sample == "area" and (height % low[0] or width % low[1]):
            # not F.interpolate's "area" here: at a non-integer factor its bins overlap, a wider aperture
            rows = resample_matrix(height, low[0], "box", x.dtype).to(x.device)
            columns = resample_matrix(width, low[1], "box", x.dtype).to(x.device)
            sampled = rows @ flat @ columns.T
        elif sample == "area":  # an integer factor: each bin is one sensor pixel's area exactly
            sampled = F.interpolate(flat, size=low, mode="area")
        else:
            sampled = F.interpolate(flat, size=low, mode="bilinear", antialias=True, align_corners=False)
        if upsample in ("bicubic", "bilinear"):
            restored = F.interpolate(sampled, size=(height, width), mode=upsample, align_corners=False)
        else:
            rows = resample_matrix(low[0], height, upsample, x.dtype).to(x.device)
            columns = resample_matrix(low[1], width, upsample, x.dtype).to(x.device)
            restored = rows @ sampled @ columns.T
        return restored.clamp(0.0, 1.0).reshape(x.shape)

    return apply_float(image, kernel)
