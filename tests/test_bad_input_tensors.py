"""Bad tensors and seeds (issue 17): empty images come back empty, meta and sparse tensors and floats on the wrong
scale are refused with a typed error, and every seed too large for torch is named wherever a seed is taken."""

from __future__ import annotations

import pytest
import torch
from torchvision.transforms import v2

from camdegrade import CameraDegrade, DegradedDataset
from camdegrade.data import BatchDegrade
from effects_images import photo_batch
from profiles_for_tests import stochastic_profile

BIG_SEED = 2**70


@pytest.fixture(scope="module")
def degrade() -> CameraDegrade:
    return CameraDegrade(stochastic_profile(), seed=0)


@pytest.mark.parametrize("shape", [(3, 0, 0), (2, 3, 0, 5), (0, 3, 8, 8), (3, 4, 0)])
@pytest.mark.parametrize("dtype", [torch.uint8, torch.float32])
def test_an_empty_image_comes_back_empty(degrade: CameraDegrade, shape: tuple[int, ...], dtype) -> None:
    image = torch.zeros(shape, dtype=dtype)
    out = degrade(image)
    assert out.shape == shape and out.dtype == dtype


def test_an_empty_batch_comes_back_empty_from_batch_degrade() -> None:
    batch = BatchDegrade(stochastic_profile(), p=1.0, seed=0)
    for shape in [(2, 3, 0, 5), (0, 3, 8, 8)]:
        out = batch(torch.zeros(shape, dtype=torch.uint8))
        assert out.shape == shape and out.dtype == torch.uint8


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: torch.zeros(3, 8, 8, device="meta"), "meta"),
        (lambda: torch.zeros(3, 8, 8).to_sparse(), "sparse"),
        (lambda: torch.zeros(1, 3, 8, 8).to_sparse(), "sparse"),
    ],
)
def test_meta_and_sparse_tensors_are_refused(degrade: CameraDegrade, make, message: str) -> None:
    with pytest.raises(TypeError, match=message):
        degrade(make())


@pytest.mark.parametrize(
    "make, message",
    [(lambda: torch.zeros(2, 3, 8, 8, device="meta"), "meta"), (lambda: torch.zeros(2, 3, 8, 8).to_sparse(), "sparse")],
)
def test_batch_degrade_refuses_meta_and_sparse_batches(make, message: str) -> None:
    with pytest.raises(TypeError, match=message):
        BatchDegrade(stochastic_profile(), seed=0)(make())


def test_floats_on_the_0_255_scale_are_refused(degrade: CameraDegrade) -> None:
    image = torch.rand(3, 16, 16, generator=torch.Generator().manual_seed(0)) * 255
    with pytest.raises(
        ValueError, match=r"in \[0, 1\], got values in \[0\.\d+, 25\d\.?\d*\]; scale 0\.\.255 images by 1/255"
    ):
        degrade(image)


def test_floats_on_the_minus_one_to_one_scale_are_refused(degrade: CameraDegrade) -> None:
    image = torch.rand(3, 16, 16, generator=torch.Generator().manual_seed(0)) * 2 - 1
    with pytest.raises(
        ValueError, match=r"in \[0, 1\], got values in \[-0\.9\d+, 0\.9\d+\].*map \[-1, 1\] images with \(x \+ 1\) / 2"
    ):
        degrade(image)


def test_bicubic_overshoot_is_tolerated_and_clamped(degrade: CameraDegrade) -> None:
    """Bicubic resizing of photos overshoots [0, 1] a little (here about -0.035 to 1.003): that is not an error."""
    resize = v2.Resize((300, 300), interpolation=v2.InterpolationMode.BICUBIC, antialias=True)
    image = resize(photo_batch())
    assert float(image.min()) < -0.02 and float(image.max()) > 1.0
    out = degrade(image)
    assert out.shape == image.shape and float(out.min()) >= 0.0 and float(out.max()) <= 1.0


def test_values_just_past_the_tolerance_are_refused(degrade: CameraDegrade) -> None:
    image = torch.full((3, 8, 8), 0.5)
    image[0, 0, 0] = 1.2
    with pytest.raises(ValueError, match=r"got values in \[0\.5, 1\.2\]"):
        degrade(image)


def test_batch_degrade_never_returns_mixed_scales() -> None:
    batch = BatchDegrade(stochastic_profile(), p=0.5, seed=0)
    images = torch.rand(8, 3, 8, 8, generator=torch.Generator().manual_seed(0)) * 255
    with pytest.raises(ValueError, match=r"scale 0\.\.255 images by 1/255"):
        batch(images)


def test_the_scale_check_is_refused_on_nan_first(degrade: CameraDegrade) -> None:
    image = torch.rand(3, 8, 8)
    image[0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="NaN or infinite"):
        degrade(image)


@pytest.mark.parametrize(
    "make",
    [
        lambda: CameraDegrade(stochastic_profile(), seed=BIG_SEED),
        lambda: DegradedDataset([torch.zeros(3, 8, 8)], stochastic_profile(), seed=BIG_SEED),
        lambda: BatchDegrade(stochastic_profile(), seed=BIG_SEED),
    ],
)
def test_a_seed_too_large_for_torch_is_named(make) -> None:
    with pytest.raises(ValueError, match=rf"seed must be an integer from -2\*\*63 to 2\*\*64 - 1, got seed={BIG_SEED}"):
        make()
