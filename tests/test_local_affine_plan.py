"""The local-affine network's CPU plan (``LocalAffineInference``): the module's output up to float32 rounding."""

from __future__ import annotations

import copy

import pytest
import torch
from skimage import data

from camdegrade import load_profile
from camdegrade.network import FIELD_UPSAMPLING, SIZE_MULTIPLE, LocalAffineNet, piecewise_linear, smoothed
from camdegrade.network.inference import cpu_inference, run_network
from camdegrade.network.inference_local_affine import (
    BILINEAR_PHASES,
    ColourFilter,
    CurveTable,
    LocalAffineInference,
    upsampled_field,
)

#: Largest difference from the module: the plan only sums in another order.
TOLERANCE = 2e-6
#: (N, 3, H, W): 1 pixel, sizes that are not multiples of 4, a batch, and 128² (1024 encoder pixels: from there the
#: first decoder product skips channels that are zero over the image).
SIZES = [(1, 3, 1, 1), (2, 3, 5, 7), (3, 3, 37, 61), (1, 3, 64, 48), (2, 3, 132, 128)]


def _network(upsample: str = "bilinear", seed: int = 0, width: int = 16, curves: bool = False) -> LocalAffineNet:
    """A LocalAffineNet with every parameter drawn small (so that few outputs are clamped); its curves (if any) bent
    away from the identity."""
    network = LocalAffineNet(width, upsample=upsample, curves=curves)
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for parameter in network.parameters():
            parameter.copy_(torch.randn(parameter.shape, generator=generator) * 0.08)
        network.linear.weight[:, :, 3, 3] += torch.eye(3)
        if curves:
            network.curve.copy_(torch.linspace(0, 1, network.curve.shape[-1]) ** torch.tensor([0.6, 1.3]).view(2, 1, 1))
    return network.eval()


def _image(shape: tuple[int, ...], seed: int = 1) -> torch.Tensor:
    return torch.rand(shape, generator=torch.Generator().manual_seed(seed))


#: Both field upsamplings without curves, and one with them.
NETWORKS = [(upsample, False) for upsample in FIELD_UPSAMPLING] + [("smooth", True)]


@pytest.mark.parametrize(("upsample", "curves"), NETWORKS)
@pytest.mark.parametrize("shape", SIZES)
def test_the_plan_follows_the_module_at_every_size(shape, upsample, curves):
    network = _network(upsample, curves=curves)
    image = _image(shape)
    with torch.no_grad():
        exact = network(image)
    fast = LocalAffineInference(network).run(image)
    assert fast.shape == exact.shape and fast.dtype == torch.float32 and fast.is_contiguous()
    assert 0.0 < float(exact.mean()) < 1.0 and float((exact - image).abs().mean()) > 0.01  # not a pass-through
    assert (fast - exact).abs().max() < TOLERANCE


def test_the_plan_skips_channels_that_are_zero_over_the_image():
    network = _network()
    with torch.no_grad():
        network.encode2.bias[::2] = -1e3  # every other channel can never fire
    image = _image((1, 3, 128, 128), seed=7)
    plan = LocalAffineInference(network)
    with torch.no_grad():
        hidden = network.encode(image)
        assert int((hidden.amax(dim=(0, 2, 3)) > 0).sum()) <= network.encode2.out_channels // 2
        assert (plan.run(image) - network(image)).abs().max() < TOLERANCE


def test_every_image_gets_the_bytes_it_gets_alone():
    plan = LocalAffineInference(_network())
    for shape in [(3, 3, 24, 20), (3, 3, 128, 136)]:
        batch = _image(shape, seed=6)
        together = plan.run(batch)
        for index in range(shape[0]):
            assert torch.equal(plan.run(batch[index : index + 1]), together[index : index + 1])


@pytest.mark.parametrize("curves", [False, True])
def test_uint8_images_are_read_as_their_value_over_255(curves):
    """With curves, a byte image's input curve is a table lookup: the same bytes as the curve on the floats."""
    plan = LocalAffineInference(_network(curves=curves))
    image = torch.randint(0, 256, (2, 3, 41, 37), generator=torch.Generator().manual_seed(3), dtype=torch.uint8)
    assert torch.equal(plan.run(image), plan.run(image.float() / 255))


def test_run_network_uses_the_plan_without_autograd_and_the_module_with_it():
    network = _network()
    image = _image((1, 3, 32, 32))
    with torch.no_grad():
        assert torch.equal(run_network(network, image), cpu_inference(network, torch.float32).run(image))
    trainable = image.clone().requires_grad_(True)
    output = run_network(network, trainable)
    output.mean().backward()
    assert output.grad_fn is not None and trainable.grad is not None and float(trainable.grad.abs().sum()) > 0


def test_the_cached_plan_follows_the_weights_and_the_upsampling():
    network = _network()
    image = _image((1, 3, 48, 48))
    first = cpu_inference(network, torch.float32)
    assert cpu_inference(network, torch.float32) is first
    network.upsample = "smooth"
    smooth = cpu_inference(network, torch.float32)
    assert smooth is not first and smooth.smooth
    with torch.no_grad():
        assert (smooth.run(image) - network(image)).abs().max() < TOLERANCE
        network.decode2.bias += 0.01
        assert (cpu_inference(network, torch.float32).run(image) - network(image)).abs().max() < TOLERANCE


def test_the_bfloat16_plan_keeps_8_bit_outputs_within_one_level():
    """bfloat16 runs the encoder and decoder only; the field, the filter and the output stay float32 (the built-in's
    network, on a photograph)."""
    network = load_profile("city100-iphonex").network
    image = torch.from_numpy(data.astronaut()).permute(2, 0, 1)[None, :, ::4, ::4].contiguous()
    with torch.no_grad():
        exact = (network(image.float() / 255) * 255).round()
    plan = LocalAffineInference(network, torch.bfloat16)
    low = (plan.run(image) * 255).round()
    assert plan.dtype == torch.bfloat16 and low.dtype == torch.float32
    assert float(((low - exact).abs() <= 1).float().mean()) >= 0.999
    assert float((low - exact).abs().max()) > 0  # it did run in bfloat16


def test_the_plan_refuses_other_dtypes():
    with pytest.raises(ValueError, match=r"dtype must be torch.float32 or torch.bfloat16, got dtype=torch.float16"):
        LocalAffineInference(_network(), torch.float16)
    with pytest.raises(ValueError, match=r"dtype must be torch.float32 or torch.bfloat16, got dtype=torch.float16"):
        cpu_inference(copy.deepcopy(_network()), torch.float16)


@pytest.mark.parametrize("smooth", [False, True])
@pytest.mark.parametrize("size", [(1, 1), (1, 5), (7, 9), (56, 64), (70, 65)])  # the last: interpolated
def test_the_field_is_upsampled_as_the_module_does_it(size, smooth):
    field = torch.randn(1, 12, *size, generator=torch.Generator().manual_seed(8))
    exact = torch.nn.functional.interpolate(field, scale_factor=4, mode="bilinear", align_corners=False)
    exact = smoothed(exact) if smooth else exact
    ours = upsampled_field(field, smooth)
    assert ours.shape == exact.shape and (ours - exact).abs().max() < 1e-5


@pytest.mark.parametrize("size", [(1, 1), (5, 7), (44, 44), (61, 37), (132, 128)])  # widths 7, 44 and 37 padded
def test_the_filter_is_the_modules_convolution(size):
    """The unrolled convolution does the plain one's products and sums: the same values."""
    network = _network(seed=4)
    image = _image((1, 3, *size), seed=5)
    with torch.no_grad():
        exact = network.filtered(image)
    ours = ColourFilter(network.linear.weight, network.linear.bias)(image)
    assert ours.shape == exact.shape and torch.equal(ours, exact)


def test_the_curve_table_gives_the_curves_values_exactly():
    knots = torch.rand(3, 17, generator=torch.Generator().manual_seed(2)) * 1.2 - 0.1
    values = torch.rand(1, 3, 37, 41, generator=torch.Generator().manual_seed(3)) * 1.4 - 0.2  # some outside [0, 1]
    assert torch.equal(CurveTable(knots)(values), piecewise_linear(values, knots))


def test_the_bilinear_phases_are_those_of_the_networks_upsampling():
    assert len(BILINEAR_PHASES) == SIZE_MULTIPLE
