"""Inputs that used to be skipped without a word: numpy HWC images, samples without an image, several plain
tensors."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch
from torchvision import tv_tensors

import camdegrade
from camdegrade import CameraDegrade, DegradedDataset
from camdegrade.data import PairedViews, Union
from camdegrade.transform import PlainTensorsWarning
from profiles_for_tests import stochastic_profile


@pytest.fixture(scope="module")
def noisy() -> CameraDegrade:
    return CameraDegrade(stochastic_profile(), seed=0)


def hwc(seed: int = 0, height: int = 10, width: int = 14) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (height, width, 3), dtype=np.uint8)


def test_a_numpy_hwc_uint8_image_is_degraded_and_comes_back_as_numpy(noisy: CameraDegrade) -> None:
    image = hwc()
    before = image.copy()
    out = CameraDegrade(stochastic_profile(), seed=0)(image)
    assert isinstance(out, np.ndarray) and out.dtype == np.uint8 and out.shape == image.shape
    assert out.flags.c_contiguous and not np.array_equal(out, image)
    assert np.array_equal(image, before)  # never modified in place
    chw = CameraDegrade(stochastic_profile(), seed=0)(torch.from_numpy(image).permute(2, 0, 1))
    assert np.array_equal(out, chw.permute(1, 2, 0).numpy())  # the same bytes as the tensor path


@pytest.mark.parametrize("dtype", [np.float16, np.float32, np.float64])
def test_a_numpy_float_image_keeps_its_dtype(dtype) -> None:
    image = (hwc() / 255).astype(dtype)
    out = CameraDegrade(stochastic_profile(), seed=0)(image)
    assert isinstance(out, np.ndarray) and out.dtype == dtype and out.shape == image.shape
    assert not np.array_equal(out, image) and out.min() >= 0 and out.max() <= 1


def test_read_only_flipped_and_batched_numpy_images() -> None:
    image = hwc()
    read_only = image.copy()
    read_only.flags.writeable = False  # np.asarray(PIL image) is read-only; torch would warn on sharing it
    flipped = image[:, ::-1]  # negative strides, which torch.from_numpy refuses
    degrade = CameraDegrade(stochastic_profile(), seed=0)
    assert degrade(read_only).shape == image.shape and degrade(flipped).shape == image.shape
    batch = np.stack([hwc(i) for i in range(3)])
    out = degrade(batch)
    assert out.shape == batch.shape and all(not np.array_equal(a, b) for a, b in zip(out, batch))


def test_numpy_images_out_of_range_or_of_other_dtypes_are_refused(noisy: CameraDegrade) -> None:
    with pytest.raises(ValueError, match=r"expects float images in \[0, 1\]"):
        noisy(hwc().astype(np.float32))
    with pytest.raises(TypeError, match=r"numpy images of dtype uint8, float16, float32 or float64, got dtype=int64"):
        noisy(hwc().astype(np.int64))


def test_a_sample_without_an_image_is_refused(noisy: CameraDegrade) -> None:
    for sample in (np.zeros((3, 10, 14), dtype=np.uint8), {"image": np.zeros((10, 14), np.uint8), "label": 1}):
        with pytest.raises(TypeError, match="found no image in the sample"):
            noisy(sample)


def test_degraded_dataset_of_numpy_items_degrades_them() -> None:
    """Before, the 'degraded' half of such a dataset was byte-identical to the clean half."""
    items = [(hwc(i), i) for i in range(4)]
    dataset = DegradedDataset(items, stochastic_profile(), policy=PairedViews(), seed=0)
    for index, (clean, degraded) in enumerate(dataset):
        assert clean[0] is items[index][0]
        assert isinstance(degraded[0], np.ndarray) and degraded[0].dtype == np.uint8
        assert not np.array_equal(degraded[0], clean[0]) and degraded[1] == index


def test_degraded_dataset_never_returns_an_undegraded_degraded_view() -> None:
    items = [{"image": np.zeros((3, 10, 14), dtype=np.uint8), "label": 0}]  # channels first: not an HWC image
    dataset = DegradedDataset(items, stochastic_profile(), policy=Union(), seed=0)
    assert dataset[0] is items[0]  # the clean view
    with pytest.raises(TypeError, match="found no image in the sample"):
        dataset[1]


def test_a_numpy_image_beside_plain_tensors_is_the_image() -> None:
    """Like a PIL image, a numpy image is an explicit image: plain tensors beside it pass through."""
    extra = torch.zeros(3, 4, 4)
    out_image, out_extra = CameraDegrade(stochastic_profile(), seed=0)((hwc(), extra))
    assert out_extra is extra and out_image.shape == (10, 14, 3)


def test_several_plain_image_tensors_warn_once_that_only_the_first_is_degraded() -> None:
    first, second = torch.zeros(3, 8, 8, dtype=torch.uint8), torch.zeros(3, 8, 8, dtype=torch.uint8)
    degrade = CameraDegrade(stochastic_profile(), seed=0)
    with pytest.warns(PlainTensorsWarning, match="degrades only the first of 2 plain image-shaped tensors"):
        out_first, out_second = degrade([first, second])
    assert out_second is second and not torch.equal(out_first, first)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        degrade([first, second])  # once per transform
        CameraDegrade(stochastic_profile(), seed=0)([first, torch.zeros(2)])  # a plain tensor that is no image
        CameraDegrade(stochastic_profile(), seed=0)([tv_tensors.Image(first), tv_tensors.Image(second)])
    assert issubclass(PlainTensorsWarning, UserWarning)
    assert camdegrade.PlainTensorsWarning is PlainTensorsWarning  # exported where users import from
