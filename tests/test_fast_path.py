"""The reduced-precision inference path: within one 8-bit level of float32 on natural images."""

from __future__ import annotations

import copy

import pytest
import torch
from skimage import data

from camdegrade import CameraDegrade, load_profile
from camdegrade.network.inference import (
    SPARSE_MAX_LIVE,
    CpuInference,
    native_bfloat16,
    probe_channel_order,
    resolve_precision,
    run_network,
)
from conftest import PAPER_BUILT_IN

PHOTOS = ("astronaut", "chelsea", "coffee", "rocket")
#: The plan's subject is the paper's network: PAPER_BUILT_IN (the built-in until 2026-11-27) and the one before it.
OLDER_PAPER_PROFILE = PAPER_BUILT_IN.parent / "city100-iphonex-2026-11-23.safetensors"


@pytest.fixture(scope="module")
def photos() -> list[torch.Tensor]:
    return [torch.from_numpy(getattr(data, name)()).permute(2, 0, 1).contiguous() for name in PHOTOS]


def test_bfloat16_stays_within_one_level_on_999_of_1000_pixels(photos):
    profile = load_profile(PAPER_BUILT_IN)
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
        CameraDegrade(load_profile(PAPER_BUILT_IN), precision="fp8")


#: Largest difference from the module: bfloat16 keeps 8 mantissa bits; float32 only sums in another order.
PLAN_TOLERANCE = {torch.bfloat16: 0.02, torch.float32: 2e-6}
SIZES = [(1, 3, 1, 1), (2, 3, 5, 7), (3, 3, 37, 61), (1, 3, 64, 48), (2, 3, 132, 128)]  # the last skips channels


@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16])
@pytest.mark.parametrize("shape", SIZES)
def test_cpu_plan_follows_the_module_at_every_size(shape, dtype):
    network = load_profile(PAPER_BUILT_IN).network
    image = torch.rand(shape, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        exact = network(image)
        fast = CpuInference(network, dtype).run(image)
    assert fast.shape == exact.shape and fast.dtype == torch.float32 and fast.is_contiguous()
    assert (fast - exact).abs().max() < PLAN_TOLERANCE[dtype]


@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16])
def test_cpu_plan_gives_every_image_the_bytes_it_gets_alone(dtype):
    """Batching and chunking must not change results: each image is computed as if it were alone, on both sides
    of the size from which zero channels are skipped."""
    network = load_profile(PAPER_BUILT_IN).network
    plan = CpuInference(network, dtype)
    for shape in [(3, 3, 24, 20), (3, 3, 128, 136)]:
        batch = torch.rand(shape, generator=torch.Generator().manual_seed(6))
        with torch.no_grad():
            together = plan.run(batch)
            for index in range(shape[0]):
                assert torch.equal(plan.run(batch[index : index + 1]), together[index : index + 1])


def test_cpu_plan_skips_channels_that_are_zero_over_the_image():
    """A network whose encoder leaves half its channels at zero gives the module's output through the sparse
    product (the gathered channels), within float32 rounding."""
    network = load_profile(PAPER_BUILT_IN).network
    sparse = copy.deepcopy(network)
    with torch.no_grad():
        sparse.encode2.bias[::2] = -1e3  # every other channel can never fire
        image = torch.rand(1, 3, 128, 128, generator=torch.Generator().manual_seed(7))
        plan = CpuInference(sparse, torch.float32)
        hidden = plan._conv_relu(plan._conv_relu(image, *plan.encode[0]), *plan.encode[1])
        assert int((hidden.amax(dim=(0, 2, 3)) > 0).sum()) <= 64
        assert (plan.run(image) - sparse(image)).abs().max() < PLAN_TOLERANCE[torch.float32]


def test_probe_orders_the_channels_photos_leave_at_zero_last(photos):
    """The channel order is a permutation, and the channels live on photographs fill a short prefix of it (what the
    native-bfloat16 plan's first decoder product runs over)."""
    network = load_profile(PAPER_BUILT_IN).network
    order = probe_channel_order(network)
    assert sorted(order.tolist()) == list(range(network.encode2.out_channels))
    with torch.no_grad():
        for image in photos:
            hidden = torch.relu(network.encode2(torch.relu(network.encode1(image[None].float() / 255))))
            live = (hidden.amax(dim=(0, 2, 3)) > 0)[order].nonzero()
            assert int(live.max()) + 1 <= SPARSE_MAX_LIVE * len(order)


@pytest.mark.skipif(not native_bfloat16(torch.device("cpu")), reason="the prefix product runs in native bfloat16")
def test_bfloat16_prefix_product_follows_the_whole_product(photos):
    """Leaving out the channels after the last live one changes only the rounding of the bfloat16 product."""
    plan = CpuInference(load_profile(PAPER_BUILT_IN).network, torch.bfloat16)
    for image in photos:
        x, first = plan._network_input(image[None])
        hidden = plan._conv_relu(plan._conv_relu(x, first, plan.encode[0][1]), *plan.encode[1])
        pixels = hidden.permute(0, 2, 3, 1).reshape(-1, hidden.shape[1])
        whole = plan._linear_relu(pixels).float()
        assert (plan._decode1(pixels).float() - whole).abs().max() <= 0.02 * whole.abs().max()


@pytest.mark.parametrize("name", [PAPER_BUILT_IN, OLDER_PAPER_PROFILE], ids=["paper", "older paper"])
def test_float32_plan_follows_the_module_on_photos(photos, name):
    """On natural photos the fitted paper networks leave about half their encoder channels at zero, so the plan takes
    its sparse product; the output stays within float32 rounding of the module."""
    network = load_profile(name).network
    plan = CpuInference(network, torch.float32)
    with torch.no_grad():
        for image in photos:
            unit = image[None].float() / 255.0
            hidden = plan._conv_relu(plan._conv_relu(unit, *plan.encode[0]), *plan.encode[1])
            assert int((hidden.amax(dim=(0, 2, 3)) > 0).sum()) <= SPARSE_MAX_LIVE * 128  # the sparse path runs
            assert (plan.run(image[None]) - network(unit)).abs().max() < PLAN_TOLERANCE[torch.float32]


def test_plan_refuses_other_dtypes():
    with pytest.raises(ValueError, match=r"dtype must be torch.float32 or torch.bfloat16, got dtype=torch.float16"):
        CpuInference(load_profile(PAPER_BUILT_IN).network, torch.float16)


@pytest.mark.parametrize("precision", ["float32", "bfloat16"])
def test_cached_plan_is_rebuilt_when_the_weights_change(precision):
    """float32 runs the cached plan on every CPU; bfloat16 only where it is native (else autocast, no plan)."""
    network = load_profile(PAPER_BUILT_IN).network
    image = torch.rand(1, 3, 32, 32, generator=torch.Generator().manual_seed(2))
    tolerance = PLAN_TOLERANCE[torch.float32 if precision == "float32" else torch.bfloat16]
    with torch.no_grad():
        before = run_network(network, image, precision)
        network.decode2.bias.add_(1.0)
        after = run_network(network, image, precision)
        assert (after - network(image)).abs().max() < tolerance
    assert (after - before).abs().mean() > 0.05


def test_bfloat16_with_autograd_keeps_the_graph():
    network = load_profile(PAPER_BUILT_IN).network.requires_grad_(True)
    output = run_network(network, torch.rand(1, 3, 16, 16), "bfloat16")
    assert output.requires_grad
    output.mean().backward()
    assert network.encode1.weight.grad is not None


@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16])
@pytest.mark.parametrize("shape", [(1, 3, 1, 1), (2, 3, 5, 7), (1, 3, 64, 48)])
def test_cpu_plan_reads_uint8_as_value_over_255(shape, dtype):
    network = load_profile(PAPER_BUILT_IN).network
    image = torch.randint(0, 256, shape, dtype=torch.uint8, generator=torch.Generator().manual_seed(3))
    with torch.no_grad():
        exact = network(image.float() / 255.0)
        from_bytes = CpuInference(network, dtype).run(image)
    assert from_bytes.shape == exact.shape and from_bytes.dtype == torch.float32
    assert (from_bytes - exact).abs().max() < PLAN_TOLERANCE[dtype]


@pytest.mark.parametrize("precision", ["float32", "bfloat16"])
def test_profile_reads_uint8_like_the_same_image_in_unit_floats(precision):
    profile = load_profile(PAPER_BUILT_IN)
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
