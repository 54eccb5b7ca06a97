"""The ISP's resampling kernel as a fitted parameter of the ``resolution`` stage: the kernels against PIL's, and the
fit naming the kernel of foreign cameras whose sensor and zoom are PIL's (tests/foreign_cameras: no camdegrade)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from PIL import Image

from camdegrade.effects import Resolution
from camdegrade.functional.resampling import resize_image
from camdegrade.functional.resolution import UPSAMPLERS, resolution_image
from effects_images import photo

#: camdegrade's kernel name of each PIL resampler (PIL's bicubic is Keys' cubic with a = −0.5).
PIL_KERNELS = {
    "nearest": Image.Resampling.NEAREST,
    "box": Image.Resampling.BOX,
    "bilinear": Image.Resampling.BILINEAR,
    "catmull_rom": Image.Resampling.BICUBIC,
    "lanczos": Image.Resampling.LANCZOS,
}


def _pil_resized(plane: np.ndarray, size: tuple[int, int], kernel: str) -> np.ndarray:
    image = Image.fromarray(plane.astype(np.float32), mode="F")
    return np.asarray(image.resize((size[1], size[0]), PIL_KERNELS[kernel]))


@pytest.mark.parametrize(
    ("kernel", "size"),
    [(k, size) for k in PIL_KERNELS for size in [(74, 100), (50, 66), (18, 24)] if (k, size) != ("box", (18, 24))],
)
def test_each_kernel_is_pils(kernel: str, size: tuple[int, int]) -> None:
    """Up, by a non-integer factor, and down (antialiased, the kernel widened): equal to PIL's on float images. Not
    held: a box *reduction* by a non-integer factor (13 % of the pixels differ, by up to 0.11: which input pixels
    PIL's box takes at a fractional edge is its own), which camdegrade never does (the ISP's kernel only upsamples)."""
    plane = np.random.default_rng(0).random((37, 50)).astype(np.float32) * 0.6 + 0.2
    ours = resize_image(torch.from_numpy(plane).double().expand(3, -1, -1), size, kernel)[0].numpy()
    assert np.abs(ours - _pil_resized(plane, size, kernel)).max() < 1e-5


def test_the_default_kernels_are_unchanged() -> None:
    """bicubic and bilinear stay torch's interpolation (profiles saved before keep their look)."""
    image = photo()[None]
    expected = torch.nn.functional.interpolate(
        torch.nn.functional.interpolate(image, size=(16, 16), mode="bilinear", antialias=True),
        size=(32, 32),
        mode="bicubic",
    ).clamp(0, 1)
    assert torch.equal(resolution_image(photo(long_side=32)[None], 0.5), expected) or image.shape[-1] != 32
    assert Resolution(0.5).upsample == "bicubic" and Resolution.from_config({}).upsample == "bicubic"
    with pytest.raises(ValueError, match=r"upsample must be one of .*, got upsample='cubic'"):
        Resolution(0.5, "cubic")


@pytest.mark.parametrize("upsample", UPSAMPLERS)
def test_fit_is_exact_on_its_own_kernels(upsample: str) -> None:
    sources = [photo(name, 96) for name in ("astronaut", "coffee")]
    targets = [resolution_image(source, 0.5, upsample) for source in sources]
    fitted = Resolution.fit(sources, targets)
    assert float(fitted.scale) == 0.5
    assert fitted.upsample == upsample or {fitted.upsample, upsample} == {"box", "nearest"}
