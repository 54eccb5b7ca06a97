"""The reduced-precision inference path: within one 8-bit level of float32 on natural images."""

from __future__ import annotations

import pytest
import torch
from skimage import data

from camdegrade import CameraDegrade, load_profile
from camdegrade.network import BFloat16Inference, native_bfloat16, resolve_precision, run_network

PHOTOS = ("astronaut", "chelsea", "coffee", "rocket")


@pytest.fixture(scope="module")
def photos() -> list[torch.Tensor]:
    return [torch.from_numpy(getattr(data, name)()).permute(2, 0, 1).contiguous() for name in PHOTOS]


def test_bfloat16_stays_within_one_level_on_999_of_1000_pixels(photos):
    profile = load_profile("city100-iphonex")
    exact = CameraDegrade(profile, precision="float32", seed=0)
    fast = CameraDegrade(profile, precision="bfloat16", seed=0)
    within, total, largest = 0, 0, 0
    for image in photos:
        difference = (exact(image).int() - fast(image).int()).abs()
        within += int((difference <= 1).sum())
        total += difference.numel()
        largest = max(largest, int(difference.max()))
    assert within / total >= 0.999, f"only {within / total:.5f} of pixels within 1 level (largest {largest})"


def test_auto_picks_bfloat16_only_where_it_is_native():
    expected = "bfloat16" if native_bfloat16(torch.device("cpu")) else "float32"
    assert resolve_precision("auto", torch.device("cpu")) == expected
    assert resolve_precision("float32", torch.device("cpu")) == "float32"


def test_unknown_precision_is_refused():
    with pytest.raises(ValueError, match=r"precision must be one of \('auto', 'float32', 'bfloat16'\), got"):
        CameraDegrade(load_profile("city100-iphonex"), precision="fp8")


@pytest.mark.parametrize("shape", [(1, 3, 1, 1), (2, 3, 5, 7), (3, 3, 37, 61), (1, 3, 64, 48)])
def test_bfloat16_plan_follows_the_module_at_every_size(shape):
    network = load_profile("city100-iphonex").network
    image = torch.rand(shape, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        exact = network(image)
        fast = BFloat16Inference(network).run(image)
    assert fast.shape == exact.shape and fast.dtype == torch.float32 and fast.is_contiguous()
    assert (fast - exact).abs().max() < 0.02  # bfloat16 keeps 8 mantissa bits


def test_cached_plan_is_rebuilt_when_the_weights_change():
    network = load_profile("city100-iphonex").network
    image = torch.rand(1, 3, 32, 32, generator=torch.Generator().manual_seed(2))
    with torch.no_grad():
        before = run_network(network, image, "bfloat16")
        network.decode2.bias.add_(1.0)
        after = run_network(network, image, "bfloat16")
        assert (after - network(image)).abs().max() < 0.02
    assert (after - before).abs().mean() > 0.05


def test_bfloat16_with_autograd_keeps_the_graph():
    network = load_profile("city100-iphonex").network.requires_grad_(True)
    output = run_network(network, torch.rand(1, 3, 16, 16), "bfloat16")
    assert output.requires_grad
    output.mean().backward()
    assert network.encode1.weight.grad is not None


@pytest.mark.parametrize("shape", [(1, 3, 1, 1), (2, 3, 5, 7), (1, 3, 64, 48)])
def test_bfloat16_plan_reads_uint8_as_value_over_255(shape):
    network = load_profile("city100-iphonex").network
    image = torch.randint(0, 256, shape, dtype=torch.uint8, generator=torch.Generator().manual_seed(3))
    with torch.no_grad():
        exact = network(image.float() / 255.0)
        from_bytes = BFloat16Inference(network).run(image)
    assert from_bytes.shape == exact.shape and from_bytes.dtype == torch.float32
    assert (from_bytes - exact).abs().max() < 0.02


@pytest.mark.parametrize("precision", ["float32", "bfloat16"])
def test_profile_reads_uint8_like_the_same_image_in_unit_floats(precision):
    profile = load_profile("city100-iphonex")
    image = torch.randint(0, 256, (2, 3, 24, 20), dtype=torch.uint8, generator=torch.Generator().manual_seed(4))
    params = profile.make_params(image.shape, torch.Generator().manual_seed(5))
    with torch.no_grad():
        from_bytes = profile(image, params, precision=precision)
        from_floats = profile(image.float() / 255.0, params, precision=precision)
    assert from_bytes.dtype == torch.float32
    if precision == "float32":
        assert torch.equal(from_bytes, from_floats)
    else:  # the 1/255 sits in the first layer's bfloat16 weights instead of in the image
        assert (from_bytes - from_floats).abs().max() < 0.02
