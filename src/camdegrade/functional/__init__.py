"""Pure image kernels on ``[..., 3, H, W]`` uint8 or float tensors, with per-sample parameters.

Kernels keep the input's dtype, device and shape, never modify their input (the in-place ``*_`` forms excepted)
and draw no random numbers: noise kernels take pre-drawn standard normals, so every degradation can be replayed
exactly. This package imports nothing from the rest of camdegrade but the leaf helper ``camdegrade._support.pixels``.
"""

from camdegrade.functional.codec import jpeg_image
from camdegrade.functional.isp.color import (
    color_matrix_image,
    linear_to_srgb,
    linear_to_srgb_,
    srgb_to_linear,
    srgb_to_linear_,
    white_balance_image,
)
from camdegrade.functional.isp.response import frequency_response_image
from camdegrade.functional.isp.sharpen import denoise_image, unsharp_mask_image
from camdegrade.functional.isp.tone import tone_curve, tone_curve_image
from camdegrade.functional.optics.blur import (
    blur_image,
    blur_planes,
    convolve_image,
    convolve_separable,
    psf_kernel,
    separable_taps,
)
from camdegrade.functional.optics.geometry import (
    chromatic_aberration_image,
    distortion_image,
    misalignment_image,
    relative_radius,
    vignetting_image,
)
from camdegrade.functional.sensor.noise import poisson_gaussian_noise_image
from camdegrade.functional.sensor.resolution import resolution_image

__all__ = [
    "blur_image",
    "blur_planes",
    "chromatic_aberration_image",
    "color_matrix_image",
    "convolve_image",
    "convolve_separable",
    "denoise_image",
    "distortion_image",
    "frequency_response_image",
    "jpeg_image",
    "linear_to_srgb",
    "linear_to_srgb_",
    "misalignment_image",
    "poisson_gaussian_noise_image",
    "psf_kernel",
    "relative_radius",
    "resolution_image",
    "separable_taps",
    "srgb_to_linear",
    "srgb_to_linear_",
    "tone_curve",
    "tone_curve_image",
    "unsharp_mask_image",
    "vignetting_image",
    "white_balance_image",
]
