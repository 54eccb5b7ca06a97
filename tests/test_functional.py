"""The kernel battery: identity, dtype/device/shape, batching, no in-place edits, monotone strength, errors."""

from __future__ import annotations

import ast
import re
from collections.abc import Callable
from itertools import pairwise
from pathlib import Path
from typing import Any

import pytest
import torch
from torch import Tensor

import camdegrade.functional as F
import camdegrade.functional.optics.blur as blur_module
from effects_images import photo, photo_batch

Kwargs = Callable[[Tensor, Any], dict[str, Any]]


def _noise_kwargs(image: Tensor, strength: Any) -> dict[str, Any]:
    # One field of draws broadcast over the batch, so a sample's noise does not depend on its batch index.
    normal = torch.randn(image.shape[-3:], generator=torch.Generator().manual_seed(0))
    a = torch.as_tensor(strength, dtype=torch.float32)
    return {"a": a[..., None].expand(*a.shape, 3), "b": 0.0, "normal": normal}


_CROSS_TALK = torch.tensor([[0.2, 0.1, 0.0], [0.0, -0.1, 0.1], [0.1, 0.0, -0.3]])

# name → (kernel, kwargs for a strength, neutral strength, increasing strengths, per-sample strengths for N=3)
KERNELS: dict[str, tuple[Callable[..., Tensor], Kwargs, Any, list[Any], Tensor]] = {
    "blur": (F.blur_image, lambda im, s: {"sigma": s}, 0.0, [0.5, 1.0, 2.0, 4.0], torch.tensor([0.0, 0.7, 2.5])),
    "motion_blur": (
        F.blur_image,
        lambda im, s: {"sigma": 0.0, "motion_length": s, "motion_angle": 30.0},
        0.0,
        [1.0, 3.0, 6.0, 10.0],
        torch.tensor([2.0, 0.0, 7.0]),
    ),
    "noise": (
        F.poisson_gaussian_noise_image,
        _noise_kwargs,
        0.0,
        [0.001, 0.004, 0.016],
        torch.tensor([0.0, 0.01, 0.003]),
    ),
    "color": (
        F.color_matrix_image,
        lambda im, s: {"matrix": torch.eye(3) + torch.as_tensor(s)[..., None, None] * _CROSS_TALK},
        0.0,
        [0.25, 0.5, 1.0],
        torch.tensor([0.0, 0.5, 1.0]),
    ),
    "white_balance": (
        F.white_balance_image,
        lambda im, s: {"gains": 1.0 + torch.as_tensor(s)[..., None] * torch.tensor([0.3, 0.0, -0.3])},
        0.0,
        [0.2, 0.5, 1.0],
        torch.tensor([0.0, 0.5, 1.0]),
    ),
    "tone_gamma": (
        F.tone_curve_image,
        lambda im, s: {"gamma": s},
        1.0,
        [1.2, 1.5, 2.0, 3.0],
        torch.tensor([1.0, 1.5, 0.7]),
    ),
    "tone_levels": (
        F.tone_curve_image,
        lambda im, s: {"black": s, "white": 1.0 - s},
        0.0,
        [0.05, 0.1, 0.2],
        torch.tensor([0.0, 0.1, 0.2]),
    ),
    "tone_exposure": (
        F.tone_curve_image,
        lambda im, s: {"exposure": s},
        0.0,
        [0.25, 0.5, 1.0],
        torch.tensor([0.0, -1.0, 0.5]),
    ),
    "denoise": (
        F.denoise_image,
        lambda im, s: {"sigma": 1.0, "threshold": s},
        0.0,
        [0.01, 0.03, 0.1, 0.25],
        torch.tensor([0.0, 0.02, 0.1]),
    ),
    "sharpen": (
        F.unsharp_mask_image,
        lambda im, s: {"sigma": 1.0, "amount": s, "threshold": 0.01},
        0.0,
        [0.25, 0.5, 1.0, 2.0],
        torch.tensor([0.0, 0.5, 1.5]),
    ),
    "vignetting": (F.vignetting_image, lambda im, s: {"k1": -s}, 0.0, [0.1, 0.3, 0.6], torch.tensor([0.0, -0.3, -0.6])),
    "distortion": (
        F.distortion_image,
        lambda im, s: {"k1": s},
        0.0,
        [0.02, 0.05, 0.1, 0.2],
        torch.tensor([0.0, 0.1, -0.1]),
    ),
    "chromatic_aberration": (
        F.chromatic_aberration_image,
        lambda im, s: {"red": s, "blue": -s},
        0.0,
        [0.005, 0.01, 0.03],
        torch.tensor([0.0, 0.01, -0.02]),
    ),
    "misalignment": (
        F.misalignment_image,
        lambda im, s: {"dx": s, "dy": -0.5 * s, "angle": s},
        0.0,
        [0.25, 0.5, 1.0, 2.0],
        torch.tensor([0.0, 0.5, 1.5]),
    ),
}
NAMES = sorted(KERNELS)


def _call(name: str, image: Tensor, strength: Any) -> Tensor:
    kernel, kwargs, *_ = KERNELS[name]
    return kernel(image, **kwargs(image, strength))


@pytest.mark.parametrize("name", NAMES)
def test_neutral_parameters_are_the_identity(name: str) -> None:
    image = photo_batch()
    neutral = KERNELS[name][2]
    assert (_call(name, image, neutral) - image).abs().max() <= 1 / 255
    as_bytes = (image * 255).round().to(torch.uint8)
    assert (_call(name, as_bytes, neutral).int() - as_bytes.int()).abs().max() <= 1


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("dtype", [torch.uint8, torch.float16, torch.bfloat16, torch.float32, torch.float64])
def test_dtype_shape_device_kept_and_input_untouched(name: str, dtype: torch.dtype) -> None:
    image = photo_batch(24, 32)
    image = (image * 255).round().to(dtype) if dtype == torch.uint8 else image.to(dtype)
    before, version = image.clone(), image._version
    out = _call(name, image, KERNELS[name][3][-1])
    assert out.dtype == dtype and out.shape == image.shape and out.device == image.device
    assert image._version == version and torch.equal(image, before)
    assert not torch.equal(out, image)


@pytest.mark.parametrize("name", NAMES)
def test_leading_dims_and_unbatched(name: str) -> None:
    image = photo_batch(24, 32)
    strength = KERNELS[name][3][1]
    flat = _call(name, image, strength)
    single = _call(name, image[1], strength)
    torch.testing.assert_close(single, flat[1], atol=1e-5, rtol=0)
    stacked = torch.stack([image, image])
    torch.testing.assert_close(_call(name, stacked, strength), torch.stack([flat, flat]), atol=1e-5, rtol=0)


@pytest.mark.parametrize("name", NAMES)
def test_per_sample_parameters_equal_per_image_results(name: str) -> None:
    image = photo_batch(24, 32)
    strengths = KERNELS[name][4]
    batched = _call(name, image, strengths)
    for index in range(image.shape[0]):
        alone = _call(name, image[index : index + 1], strengths[index : index + 1])
        torch.testing.assert_close(batched[index : index + 1], alone, atol=1e-5, rtol=0)


@pytest.mark.parametrize("name", NAMES)
def test_strength_is_monotone(name: str) -> None:
    image = photo_batch()
    distances = [float((_call(name, image, s) - image).pow(2).mean()) for s in KERNELS[name][3]]
    assert all(b > a for a, b in pairwise(distances)), distances


@pytest.mark.parametrize("name", NAMES)
def test_empty_batch_keeps_its_shape(name: str) -> None:
    image = torch.rand(0, 3, 8, 8)
    assert _call(name, image, KERNELS[name][2]).shape == (0, 3, 8, 8)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("name", [*NAMES, "jpeg"])
def test_cuda_matches_cpu(name: str) -> None:
    image = photo_batch(24, 32)
    if name == "jpeg":
        torch.testing.assert_close(F.jpeg_image(image.cuda(), 50).cpu(), F.jpeg_image(image, 50))
        return
    strength = KERNELS[name][3][1]
    kwargs = KERNELS[name][1](image, strength)
    on_gpu = {k: v.cuda() if isinstance(v, Tensor) else v for k, v in kwargs.items()}
    torch.testing.assert_close(
        KERNELS[name][0](image.cuda(), **on_gpu).cpu(), _call(name, image, strength), atol=1e-4, rtol=0
    )


def test_jpeg_round_trip_quality_and_dtypes() -> None:
    image = photo_batch()
    errors = [float((F.jpeg_image(image, q) - image).pow(2).mean()) for q in (95, 75, 50, 20, 5)]
    assert all(b > a for a, b in pairwise(errors))
    high = F.jpeg_image(image, 100)
    assert -10 * torch.log10((high - image).pow(2).mean()) > 35  # no neutral quality, but q=100 is close
    as_bytes = (image * 255).round().to(torch.uint8)
    out = F.jpeg_image(as_bytes, torch.tensor([10, 50, 90]))
    assert out.dtype == torch.uint8 and out.shape == as_bytes.shape
    for index, quality in enumerate((10, 50, 90)):
        assert torch.equal(out[index], F.jpeg_image(as_bytes[index], quality))
    assert torch.equal(F.jpeg_image(as_bytes, 50), F.jpeg_image(as_bytes, 50))
    assert F.jpeg_image(image.double(), 50).dtype == torch.float64


@pytest.mark.parametrize("quality", [0, 101, 50.5, -3])
def test_jpeg_rejects_bad_quality(quality: float) -> None:
    with pytest.raises(ValueError, match=re.escape(f"quality must be an integer from 1 to 100, got quality={quality}")):
        F.jpeg_image(photo_batch(), quality)


def test_errors_name_the_argument() -> None:
    image = photo_batch()
    with pytest.raises(TypeError, match=r"uint8 or a floating-point tensor, got dtype torch\.int32"):
        F.blur_image(image.to(torch.int32), 1.0)
    with pytest.raises(ValueError, match=r"\[..., 3, H, W\], got shape \(4, 8, 8\)"):
        F.vignetting_image(torch.rand(4, 8, 8), -0.2)
    with pytest.raises(
        ValueError, match=r"sigma must be a scalar or have leading shape matching .* \(3,\), got shape \(2,\)"
    ):
        F.blur_image(image, torch.tensor([1.0, 2.0]))
    with pytest.raises(ValueError, match="sigma must be non-negative, got sigma=-1"):
        F.blur_image(image, -1.0)
    with pytest.raises(ValueError, match="white must be greater than black"):
        F.tone_curve_image(image, black=0.5, white=0.4)
    with pytest.raises(ValueError, match="gamma must be positive"):
        F.tone_curve_image(image, gamma=0.0)
    with pytest.raises(ValueError, match=r"matrix must have trailing shape \(3, 3\)"):
        F.color_matrix_image(image, torch.eye(2))
    with pytest.raises(ValueError, match="row_normal must be given"):
        F.poisson_gaussian_noise_image(image, 0.01, 0.0, torch.randn(image.shape), row_sigma=0.1)
    with pytest.raises(ValueError, match=r"normal must broadcast to shape \(3, 3, 48, 64\)"):
        F.poisson_gaussian_noise_image(image, 0.01, 0.0, torch.randn(3, 3, 8, 8))
    with pytest.raises(ValueError, match="a must be non-negative"):
        F.poisson_gaussian_noise_image(image, -0.01, 0.0, torch.randn(image.shape))


def test_srgb_round_trip_and_anchors() -> None:
    values = torch.linspace(0, 1, 1001, dtype=torch.float64)
    torch.testing.assert_close(F.linear_to_srgb(F.srgb_to_linear(values)), values)
    assert abs(float(F.srgb_to_linear(torch.tensor(0.5))) - 0.21404) < 1e-4


def test_psf_is_normalised_and_oriented() -> None:
    kernels = blur_module.psf_kernel(
        torch.tensor([0.0, 1.0, 3.0, 0.0]),
        torch.tensor([0.0, 1.0, 1.0, 0.0]),
        torch.tensor([0.0, 0.0, 90.0, 0.0]),
        torch.tensor([0.0, 0.0, 0.0, 8.0]),
        torch.tensor([0.0, 0.0, 0.0, 0.0]),
    )
    torch.testing.assert_close(kernels.sum((-1, -2)), torch.ones(4))
    center = kernels.shape[-1] // 2
    assert kernels[0, center, center] == 1  # zero blur is an impulse
    rotated = kernels[2]  # major axis rotated to vertical
    assert rotated[:, center].var() > rotated[center, :].var()
    horizontal = kernels[3]  # horizontal motion spreads along x only
    assert horizontal[center].sum() > 0.99 and horizontal[center, center - 4 : center + 5].sum() > 0.99


def test_fft_and_direct_convolution_agree(monkeypatch: pytest.MonkeyPatch) -> None:
    image = photo_batch(32, 40)
    sigmas = torch.tensor([0.8, 2.0, 3.5])
    fft = F.blur_image(image.double(), sigmas)  # float64 always goes through the FFT
    monkeypatch.setattr(blur_module, "FFT_RADIUS", 1000)
    direct = F.blur_image(image, sigmas)
    torch.testing.assert_close(fft.float(), direct, atol=1e-5, rtol=0)


def test_geometry_conventions() -> None:
    image = photo("astronaut", 64)
    moved = F.misalignment_image(image, dx=2.0, dy=-1.0)
    torch.testing.assert_close(moved[:, 4:-4, 6:-4], torch.roll(image, (-1, 2), (-2, -1))[:, 4:-4, 6:-4])
    aberrated = F.chromatic_aberration_image(image, 0.02, -0.02)
    torch.testing.assert_close(aberrated[1], image[1], atol=1e-6, rtol=0)  # green is the reference
    assert not torch.allclose(aberrated[0], image[0])
    barrel = F.distortion_image(image, 0.2)
    height, width = image.shape[-2:]
    assert torch.allclose(
        barrel[:, height // 2 - 1 : height // 2 + 1, width // 2 - 1 : width // 2 + 1],
        image[:, height // 2 - 1 : height // 2 + 1, width // 2 - 1 : width // 2 + 1],
        atol=0.02,
    )
    flat = torch.full((3, 40, 60), 0.6)
    vignetted = F.vignetting_image(flat, -0.5)
    assert vignetted[:, 20, 30].sub(0.6).abs().max() < 0.01 and (vignetted[:, 0, 0] < 0.5).all()


def test_noise_statistics_follow_the_variance_model() -> None:
    flat = torch.full((1, 3, 128, 128), 0.5)
    normal = torch.randn(flat.shape, generator=torch.Generator().manual_seed(1))
    noisy = F.poisson_gaussian_noise_image(flat, a=0.01, b=1e-4, normal=normal)
    intensity = F.srgb_to_linear(torch.tensor(0.5))
    measured = (F.srgb_to_linear(noisy) - intensity).var()
    assert abs(float(measured) / float(0.01 * intensity + 1e-4) - 1) < 0.05


def test_functional_imports_nothing_else_from_camdegrade() -> None:
    """Kernels depend on nothing but each other and the leaf helper that maps 8-bit to unit floats."""
    package = Path(F.__file__).parent
    for module in package.rglob("*.py"):
        for node in ast.walk(ast.parse(module.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("camdegrade"):
                allowed = node.module.startswith("camdegrade.functional") or node.module == "camdegrade._support.pixels"
                assert allowed, (module.name, node.module)
            if isinstance(node, ast.Import):
                assert not any(alias.name.startswith("camdegrade") for alias in node.names), module.name


def _srgb_reference(x: Tensor, decode: bool) -> Tensor:
    """IEC 61966-2-1 written the textbook way, in float64."""
    x = x.double().clamp(0, 1)
    if decode:
        return torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    return torch.where(x <= 0.0031308, x * 12.92, 1.055 * x ** (1 / 2.4) - 0.055)


@pytest.mark.parametrize("decode", [True, False], ids=["to_linear", "to_srgb"])
def test_srgb_transfer_matches_the_standard_in_every_form(decode: bool) -> None:
    values = torch.linspace(-0.1, 1.1, 200_001)
    expected = _srgb_reference(values, decode)
    plain, in_place = (F.srgb_to_linear, F.srgb_to_linear_) if decode else (F.linear_to_srgb, F.linear_to_srgb_)
    graph = plain(values.clone().requires_grad_()).detach()
    copy = values.clone()
    for result in (plain(values), in_place(copy), graph):
        assert (result.double() - expected).abs().max() < 5e-7
    assert torch.equal(copy, in_place(values.clone()))
    grid = torch.linspace(0.02, 0.98, 50, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(plain, (grid,))


@pytest.mark.parametrize(
    ("sigma_x", "sigma_y", "angle"),
    [(0.8, 0.8, 0.0), (1.5, 0.6, 0.0), (1.5, 0.6, 90.0), (1.5, 0.6, -270.0), (2.0, 2.0, 33.0), (6.0, 6.0, 0.0)],
)
def test_separable_blur_equals_the_2d_psf_convolution(sigma_x: float, sigma_y: float, angle: float) -> None:
    """Axis-aligned and isotropic Gaussians take the separable path; it must give the 2-D kernel's result,
    per sample (including a zero sigma) and when the kernel is wider than the image (replicate padding)."""
    image = torch.rand(3, 3, 20, 26, generator=torch.Generator().manual_seed(0))
    sigma_x_t = torch.tensor([sigma_x, 0.5 * sigma_x, 0.0])
    sigma_y_t = torch.tensor([sigma_y, 0.5 * sigma_y, 0.0])
    angle_t = torch.full((3,), angle)
    assert F.separable_taps(sigma_x_t, sigma_y_t, angle_t, torch.zeros(3)) is not None
    kernels = F.psf_kernel(sigma_x_t, sigma_y_t, angle_t)
    expected = blur_module._convolve(image, kernels)
    # The separable path leaves out taps lighter than NEGLIGIBLE_TAP (the 0.4-sigma sample's outer pair here).
    torch.testing.assert_close(F.blur_image(image, sigma_x_t, sigma_y_t, angle_t), expected, atol=1e-4, rtol=0)


def test_rotated_or_moving_psfs_are_not_taken_as_separable() -> None:
    zeros = torch.zeros(1)
    assert F.separable_taps(torch.tensor([1.5]), torch.tensor([0.6]), torch.tensor([30.0]), zeros) is None
    assert F.separable_taps(torch.ones(1), torch.ones(1), zeros, torch.tensor([3.0])) is None


@pytest.mark.parametrize("linear", [True, False])
def test_noise_kernel_keeps_a_graph_and_matches_its_in_place_form(linear: bool) -> None:
    image = torch.rand(2, 3, 12, 10, generator=torch.Generator().manual_seed(4)) * 0.8 + 0.1
    normal = torch.randn(image.shape, generator=torch.Generator().manual_seed(5))
    rows = torch.randn(2, 3, 12, 1, generator=torch.Generator().manual_seed(6))
    args = (0.01, 1e-4, normal)
    plain = F.poisson_gaussian_noise_image(image, *args, row_sigma=0.01, row_normal=rows, linear=linear)
    tracked = image.clone().requires_grad_()
    graph = F.poisson_gaussian_noise_image(tracked, *args, row_sigma=0.01, row_normal=rows, linear=linear)
    graph.sum().backward()
    assert tracked.grad is not None and bool(torch.isfinite(tracked.grad).all())
    torch.testing.assert_close(graph.detach(), plain, atol=1e-6, rtol=0)


def test_separable_taps_leave_out_only_negligible_outer_taps() -> None:
    across, down = F.separable_taps(torch.tensor([0.785]), torch.tensor([0.785]), torch.zeros(1), torch.zeros(1))
    # TRUNCATE · sigma gives a radius of 4; the taps at ±4 weigh 1.2e-6, those at ±3 3.5e-4.
    assert across.shape == (1, 7) and down.shape == (1, 7)
    torch.testing.assert_close(across.sum(), torch.tensor(1.0))
    assert float(across.min()) > blur_module.NEGLIGIBLE_TAP
    wide, _ = F.separable_taps(torch.tensor([3.0]), torch.tensor([3.0]), torch.zeros(1), torch.zeros(1))
    assert wide.shape == (1, 25)  # every tap of a 3-sigma Gaussian truncated at 4 sigma weighs more than 1e-5


@pytest.mark.parametrize(("gamma", "black_at_most"), [(1.3, 3e-10), (0.25, 1e-9), (0.1, 0.0)])
def test_in_place_levels_gamma_keeps_black_below_any_quantisation_step(gamma: float, black_at_most: float) -> None:
    from camdegrade.functional.isp.tone import levels_gamma_

    values = torch.linspace(-0.1, 1.1, 1201)
    black, white = torch.tensor(0.05), torch.tensor(0.95)
    curve = levels_gamma_(values.clone(), torch.tensor(gamma), black, white)
    levels = ((values - black) / (white - black)).clamp(0, 1)  # float32, as the kernel computes them
    expected = levels.double() ** gamma
    black = levels == 0
    assert float(curve[black].max()) <= black_at_most
    assert (curve[~black].double() - expected[~black]).abs().max() < 2e-6
