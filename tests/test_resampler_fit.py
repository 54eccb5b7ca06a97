"""The ISP's resampling kernel as a fitted parameter of the ``resolution`` stage: the kernels against PIL's, and the
fit naming the kernel of foreign cameras whose sensor and zoom are PIL's (tests/foreign_cameras: no camdegrade)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from PIL import Image

from camdegrade.effects import Resolution
from camdegrade.functional.sensor.resampling import resize_image
from camdegrade.functional.sensor.resolution import UPSAMPLERS, resolution_image
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
    image = photo(long_side=32)[None, :, :32, :32]
    for upsample in ("bicubic", "bilinear"):
        sampled = torch.nn.functional.interpolate(image, size=(16, 16), mode="bilinear", antialias=True)
        expected = torch.nn.functional.interpolate(sampled, size=(32, 32), mode=upsample).clamp(0, 1)
        assert torch.equal(resolution_image(image, 0.5, upsample), expected)
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


def _foreign_pairs(sensor: str, scale: float, zoom: str) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
    """Clean scenes and a foreign sensor of ``scale`` of their pixels (PIL ``sensor``) zoomed back (PIL ``zoom``),
    float, no noise (tests/foreign_cameras' resampler)."""
    from foreign_cameras import scenes
    from foreign_cameras.sensor import resize

    sources, targets = [], []
    for clean in scenes(4, 96, seed=5):
        x = clean.astype(np.float64) / 255
        low = resize(x, (round(96 * scale), round(96 * scale)), sensor)
        y = np.clip(resize(low, (96, 96), zoom), 0, 1)
        sources.append(torch.from_numpy(x.transpose(2, 0, 1).copy()).float())
        targets.append(torch.from_numpy(y.transpose(2, 0, 1).copy()).float())
    return sources, targets


@pytest.mark.parametrize(
    ("sensor", "scale", "zoom", "named", "sampled"),
    [
        # A bilinear sensor (the stage's own reduction): PIL's kernel named, its bicubic as Keys' a = −0.5.
        ("bilinear", 2 / 3, "bilinear", {"bilinear"}, "antialiased"),
        ("bilinear", 2 / 3, "bicubic", {"catmull_rom"}, "antialiased"),
        ("bilinear", 2 / 3, "lanczos", {"lanczos"}, "antialiased"),
        # PIL's box upscale by 1.5 is pixel replication (our nearest); PIL's nearest at 1.5 replicates other pixels
        # (its rounding of the centres), which no kernel here matches: the fit takes the cubic.
        ("bilinear", 2 / 3, "box", {"nearest"}, "antialiased"),
        ("bilinear", 2 / 3, "nearest", {"catmull_rom"}, "antialiased"),
        # A box sensor (each pixel integrates its area): sampled over the area, PIL's kernel named (with the
        # bilinear reduction alone, which blurs more, the fit took a sharper kernel than PIL's: bilinear read as
        # catmull_rom, bicubic as lanczos); box and nearest are one kernel at 2×.
        ("box", 1 / 2, "bilinear", {"bilinear"}, "area"),
        ("box", 1 / 2, "bicubic", {"catmull_rom"}, "area"),
        ("box", 1 / 2, "lanczos", {"lanczos"}, "area"),
        ("box", 1 / 2, "nearest", {"box", "nearest"}, "area"),
        ("box", 1 / 2, "box", {"box", "nearest"}, "area"),
    ],
)
def test_fit_names_the_kernel_and_the_sampling_of_a_foreign_zoom(
    sensor: str, scale: float, zoom: str, named: set[str], sampled: str
) -> None:
    fitted = Resolution.fit(*_foreign_pairs(sensor, scale, zoom))
    assert float(fitted.scale) == pytest.approx(scale, abs=1e-6) and fitted.upsample in named
    assert fitted.sample == sampled


def test_area_sampling_is_a_box_sensor_and_the_default_is_unchanged() -> None:
    """``sample="area"``: each sensor pixel the mean of the 2×2 output pixels it covers (a box sensor: detail finer
    than its grid aliases); profiles saved without the setting keep the antialiased reduction."""
    image = photo(long_side=32)[None, :, :32, :32]
    pooled = torch.nn.functional.avg_pool2d(image, 2)
    replicated = pooled.repeat_interleave(2, -1).repeat_interleave(2, -2)
    assert torch.allclose(resolution_image(image, 0.5, "box", "area"), replicated, atol=1e-6)
    assert not torch.allclose(resolution_image(image, 0.5, "box"), replicated, atol=1e-3)
    assert Resolution(0.5).sample == "antialiased" and Resolution.from_config({}).sample == "antialiased"
    assert Resolution.from_config({"sample": "area"}).config() == {"upsample": "bicubic", "sample": "area"}
    with pytest.raises(ValueError, match=r"sample must be one of \('antialiased', 'area'\), got sample='box'"):
        Resolution(0.5, sample="box")
