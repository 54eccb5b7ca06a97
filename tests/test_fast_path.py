"""The reduced-precision inference path: within one 8-bit level of float32 on natural images."""

from __future__ import annotations

import pytest
import torch
from skimage import data

from camdegrade import CameraDegrade, load_profile
from camdegrade.network import native_bfloat16, resolve_precision

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
