"""The steps a foreign camera chains: each a frozen dataclass called as ``stage(x, rng, size)``.

``x`` is float64, (H, W, 3) or the (H, W) plane of a colour filter array, in the domain the previous stage left
(linear light after :class:`Decode`, sRGB after :class:`Encode`); ``rng`` is the capture's numpy Generator (only
noise stages draw from it); ``size`` is the (height, width) of the camera's input, which :class:`Zoom` returns to.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from foreign_cameras import codec, optics, sensor, tone
from foreign_cameras.demosaic import DEMOSAICERS

Size = tuple[int, int]


@dataclass(frozen=True)
class Stage:
    """A step of a camera's chain (subclasses say what it does and in which domain)."""

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        raise NotImplementedError


@dataclass(frozen=True)
class Decode(Stage):
    """sRGB values to linear light (the scene's radiance up to a scale)."""

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        return tone.srgb_to_linear(x)


@dataclass(frozen=True)
class Encode(Stage):
    """Linear light to sRGB, clipped to [0, 1] (saturation)."""

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        return tone.linear_to_srgb(x)


@dataclass(frozen=True)
class Defocus(Stage):
    """Defocus: convolution with a uniform disc of ``radius`` pixels (in whichever domain it is placed)."""

    radius: float

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        return optics.convolve(x, optics.disc_psf(self.radius))


@dataclass(frozen=True)
class Lens(Stage):
    """A lens PSF: Gaussian core ``sigma`` plus a halo (``halo_weight`` of the energy, ``halo_sigma`` wide)."""

    sigma: float
    halo_sigma: float = 0.0
    halo_weight: float = 0.0

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        return optics.convolve(x, optics.lens_psf(self.sigma, self.halo_sigma, self.halo_weight))


@dataclass(frozen=True)
class Motion(Stage):
    """Camera shake during the exposure: a straight streak of ``length`` pixels at ``angle`` degrees."""

    length: float
    angle: float

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        return optics.convolve(x, optics.motion_psf(self.length, self.angle))


@dataclass(frozen=True)
class Cos4Vignetting(Stage):
    """Natural vignetting, ``cos⁴`` of the field angle (``corner_angle`` degrees at the corners); linear light."""

    corner_angle: float

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        return x * optics.cos4_falloff(*x.shape[:2], self.corner_angle)[..., None]


@dataclass(frozen=True)
class PolynomialVignetting(Stage):
    """Mechanical vignetting ``1 + k1 r² + k2 r⁴`` (r 1 at the corners); linear light."""

    k1: float
    k2: float = 0.0

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        return x * optics.polynomial_falloff(*x.shape[:2], self.k1, self.k2)[..., None]


@dataclass(frozen=True)
class Misalign(Stage):
    """The frame moved by (``dx``, ``dy``) px and turned by ``angle`` degrees, resampled by PIL's ``method`` (PIL's
    bicubic transform moves sub-pixel content a little further than asked: 0.25 px → 0.34 px, measured)."""

    dx: float
    dy: float
    angle: float = 0.0
    method: str = "bicubic"

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        return optics.misalign(x, self.dx, self.dy, self.angle, sensor.RESAMPLERS[self.method])


@dataclass(frozen=True)
class Exposure(Stage):
    """Exposure: linear light times ``gain`` (a shorter or longer exposure, an aperture stop)."""

    gain: float

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        return x * self.gain


@dataclass(frozen=True)
class SensorSampling(Stage):
    """A sensor with ``scale`` of the frame's pixels: the image resampled to it by PIL's ``method``."""

    scale: float
    method: str

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        target = (max(1, round(size[0] * self.scale)), max(1, round(size[1] * self.scale)))
        return sensor.resize(x, target, self.method)


@dataclass(frozen=True)
class Zoom(Stage):
    """The ISP's resize back to the frame size by PIL's ``method``; ``eight_bit`` resizes an 8-bit RGB buffer (the
    input rounded to 8 bits, the output rounded again), otherwise float planes."""

    method: str
    eight_bit: bool = False

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        return (sensor.resize_8bit if self.eight_bit else sensor.resize)(x, size, self.method)


@dataclass(frozen=True)
class Mosaic(Stage):
    """A Bayer colour filter array of ``pattern`` (``RGGB``, ``GRBG``, ...): (H, W, 3) to one plane (H, W)."""

    pattern: str

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        return sensor.mosaic(x, self.pattern)


@dataclass(frozen=True)
class MosaicGains(Stage):
    """White balance on the Bayer plane: each site times its colour's gain (``gains``: red, green, blue)."""

    gains: tuple[float, float, float]
    pattern: str

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        masks = sensor.bayer_masks(*x.shape, self.pattern)
        return x * (masks * np.asarray(self.gains)).sum(axis=-1)


@dataclass(frozen=True)
class Demosaic(Stage):
    """Demosaicing a Bayer plane of ``pattern`` by ``method`` (``bilinear`` or ``hamilton_adams``)."""

    method: str
    pattern: str

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        return DEMOSAICERS[self.method](x, self.pattern)


@dataclass(frozen=True)
class ShotNoise(Stage):
    """Poisson-Gaussian sensor noise in linear raw: ``full_well`` electrons at full scale, ``read_std`` read
    noise (full-scale units)."""

    full_well: float
    read_std: float

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        return sensor.poisson_gaussian(x, self.full_well, self.read_std, rng)


@dataclass(frozen=True)
class WhiteNoise(Stage):
    """Independent Gaussian noise of ``std`` (full-scale units) in whichever domain it is placed."""

    std: float

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        return sensor.white_noise(x, self.std, rng)


@dataclass(frozen=True)
class RowNoise(Stage):
    """Read-out stripes: a Gaussian offset of ``std`` per row."""

    std: float

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        return sensor.row_noise(x, self.std, rng)


@dataclass(frozen=True)
class ColorMatrix(Stage):
    """A 3×3 matrix on the colour of each pixel (white balance is a diagonal one); linear light."""

    matrix: tuple[tuple[float, float, float], ...]

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        return x @ np.asarray(self.matrix, dtype=np.float64).T


@dataclass(frozen=True)
class Quantize(Stage):
    """Rounding to ``bits`` bits (an ADC, or an 8-bit buffer between two ISP blocks)."""

    bits: int = 8

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        return tone.quantize(x, self.bits)


def tone_samples(contrast: float, gamma: float, black: float, white: float) -> np.ndarray:
    """The tone curve ``contrast ∘ (black + (white − black) x^gamma)`` sampled at the 256 8-bit codes."""
    lifted = tone.gamma_curve(gamma, black, white)
    return lifted - contrast * np.sin(2.0 * np.pi * lifted) / (2.0 * np.pi)


@dataclass(frozen=True)
class ToneLUT(Stage):
    """A tone curve applied as an 8-bit table to 8-bit values (the input rounded to codes; the steep parts of the
    curve skip output codes)."""

    contrast: float = 0.0
    gamma: float = 1.0
    black: float = 0.0
    white: float = 1.0

    def table(self) -> np.ndarray:
        return tone.lut_8bit(tone_samples(self.contrast, self.gamma, self.black, self.white))

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        return tone.apply_lut(x, self.table())


@dataclass(frozen=True)
class ToneCurve(Stage):
    """The same tone curve applied to float values (interpolated; nothing quantized)."""

    contrast: float = 0.0
    gamma: float = 1.0
    black: float = 0.0
    white: float = 1.0

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        return tone.apply_curve(x, tone_samples(self.contrast, self.gamma, self.black, self.white))


@dataclass(frozen=True)
class Sharpen(Stage):
    """Unsharp masking: ``x + amount (x − gaussian_sigma(x))`` per channel (an ISP's edge enhancement)."""

    sigma: float
    amount: float

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        blurred = ndimage.gaussian_filter(x, sigma=(self.sigma, self.sigma, 0), mode="mirror")
        return x + self.amount * (x - blurred)


@dataclass(frozen=True)
class Jpeg(Stage):
    """JPEG at ``quality`` with ``subsampling`` chroma (PIL/libjpeg), at the resolution the chain is at."""

    quality: int
    subsampling: str = "4:2:0"

    def __call__(self, x: np.ndarray, rng: np.random.Generator, size: Size) -> np.ndarray:
        return codec.jpeg(x, self.quality, self.subsampling)
