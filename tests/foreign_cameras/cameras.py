"""The foreign cameras: each a factory whose docstring is its physical chain, built from :mod:`stages`.

A :class:`Camera` takes an 8-bit RGB image ``(H, W, 3)`` and a seed (an int or a tuple of ints for
:func:`numpy.random.default_rng`) and returns the capture, ``uint8 (H, W, 3)``: the same seed gives the same bytes.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from foreign_cameras.stages import (
    ColorMatrix,
    Cos4Vignetting,
    Decode,
    Defocus,
    Demosaic,
    Encode,
    Exposure,
    Jpeg,
    Lens,
    Misalign,
    Mosaic,
    MosaicGains,
    Motion,
    PolynomialVignetting,
    Quantize,
    RowNoise,
    SensorSampling,
    ShotNoise,
    Stage,
    ToneCurve,
    ToneLUT,
    WhiteNoise,
    Zoom,
)

Seed = int | Sequence[int]


@dataclass(frozen=True)
class Camera:
    """A named chain of stages applied to an 8-bit RGB image."""

    name: str
    stages: tuple[Stage, ...]

    def __call__(self, image: np.ndarray, seed: Seed) -> np.ndarray:
        """The capture of ``image`` (uint8 ``(H, W, 3)``), its randomness drawn from ``default_rng(seed)``."""
        if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
            got = f"{type(image).__name__} {getattr(image, 'dtype', '')} {getattr(image, 'shape', '')}"
            raise ValueError(f"image must be a uint8 numpy array of shape (H, W, 3), got {got}")
        rng = np.random.default_rng(seed)
        x = image.astype(np.float64) / 255.0
        size = image.shape[:2]
        for stage in self.stages:
            x = stage(x, rng, size)
        return np.round(np.clip(x, 0.0, 1.0) * 255.0).astype(np.uint8)

    def inserted(self, stage: Stage, *, before: str | None = None, after: str | None = None, name: str = "") -> Camera:
        """This camera with ``stage`` put before (or after) the first stage of class ``before`` (``after``); with
        neither, at the end."""
        kinds = [type(existing).__name__ for existing in self.stages]
        anchor = before or after
        if anchor is not None and anchor not in kinds:
            raise ValueError(f"no stage {anchor!r} in camera {self.name!r} (stages: {', '.join(kinds)})")
        index = len(kinds) if anchor is None else kinds.index(anchor) + (0 if before else 1)
        stages = (*self.stages[:index], stage, *self.stages[index:])
        return replace(self, name=name or f"{self.name}+{type(stage).__name__}", stages=stages)

    def describe(self) -> list[str]:
        """Each stage as its class and parameters, in chain order."""
        return [repr(stage) for stage in self.stages]


def _matrix(values: np.ndarray) -> tuple[tuple[float, float, float], ...]:
    return tuple(tuple(float(v) for v in row) for row in np.asarray(values))


#: Luma weights of linear sRGB (ITU-R BT.709), for the saturation of a colour matrix.
_LUMA = np.array([0.2126, 0.7152, 0.0722])


def _raw_response(mix: np.ndarray, sensitivity: Sequence[float]) -> ColorMatrix:
    """The sensor's colour response: overlapping filter passbands (``mix``, rows summing to 1) and channel
    sensitivities (green the most sensitive)."""
    return ColorMatrix(_matrix(np.diag(sensitivity) @ mix))


def _colour_correction(mix: np.ndarray, saturation: float) -> ColorMatrix:
    """The camera's colour matrix: the inverse of the filters' overlap and a saturation boost (the maker's look)."""
    boost = (1.0 - saturation) * np.tile(_LUMA, (3, 1)) + saturation * np.eye(3)
    return ColorMatrix(_matrix(boost @ np.linalg.inv(mix)))


_WEBCAM_MIX = np.array([[0.70, 0.24, 0.06], [0.16, 0.72, 0.12], [0.05, 0.27, 0.68]])
_WEBCAM_SENSITIVITY = (0.52, 1.0, 0.66)
_PHONE_MIX = np.array([[0.76, 0.20, 0.04], [0.12, 0.78, 0.10], [0.04, 0.22, 0.74]])
_PHONE_SENSITIVITY = (0.48, 1.0, 0.62)


def webcam() -> Camera:
    """A USB webcam with half the frame's pixels (the resampling base of the withheld-effect scenarios).

    sRGB → linear → lens (Gaussian core σ 0.7 px + 4 % halo of σ 4 px) → natural vignetting (cos⁴, 30° at the
    corners) → a sensor of half the pixels (PIL box: each pixel integrates its area) → the filters' colour response
    (overlapping passbands, red 0.52× and blue 0.66× as sensitive as green) → Poisson-Gaussian noise (4,000 e⁻ at full
    scale, read noise 0.2 % of it) → white balance (3 % warm of neutral) → colour matrix (inverse overlap, saturation
    1.08) → sRGB → 8 bits → contrast S-curve (+25 % slope at mid-grey) as an 8-bit table on the 8-bit values → the
    ISP's 2× upscale of its 8-bit buffer (PIL bicubic). The noise is drawn before the upscale, so it comes out
    smooth and correlated over about 2 px."""
    return Camera(
        "webcam",
        (
            Decode(),
            Lens(0.7, halo_sigma=4.0, halo_weight=0.04),
            Cos4Vignetting(30.0),
            SensorSampling(0.5, "box"),
            _raw_response(_WEBCAM_MIX, _WEBCAM_SENSITIVITY),
            ShotNoise(4000.0, 0.002),
            ColorMatrix(_matrix(np.diag([1.03 / 0.52, 1.0, 0.97 / 0.66]))),
            _colour_correction(_WEBCAM_MIX, 1.08),
            Encode(),
            Quantize(8),
            ToneLUT(contrast=0.25),
            Zoom("bicubic", eight_bit=True),
        ),
    )


def phone() -> Camera:
    """A phone-like camera with a Bayer sensor (the colour-filter-array base of the withheld-effect scenarios).

    sRGB → linear → lens (Gaussian core σ 0.5 px + 3 % halo of σ 3 px) → the filters' colour response (red 0.48×,
    blue 0.62× green) → RGGB Bayer mosaic at the frame's resolution → Poisson-Gaussian noise per site (2,500 e⁻ at
    full scale, read noise 0.15 %) → white balance on the mosaic → Hamilton-Adams demosaic (edge-directed green,
    bilinear colour differences) → colour matrix (inverse overlap, saturation 1.15) → sRGB → 8 bits → tone (γ 0.95,
    +15 % contrast at mid-grey) as an 8-bit table on the 8-bit values. Its output keeps the demosaic's 2×2 phase
    pattern in the noise and skips the output codes where the table is steeper than 1."""
    return Camera(
        "phone",
        (
            Decode(),
            Lens(0.5, halo_sigma=3.0, halo_weight=0.03),
            _raw_response(_PHONE_MIX, _PHONE_SENSITIVITY),
            Mosaic("RGGB"),
            ShotNoise(2500.0, 0.0015),
            MosaicGains((1.0 / 0.48, 1.0, 1.0 / 0.62), "RGGB"),
            Demosaic("hamilton_adams", "RGGB"),
            _colour_correction(_PHONE_MIX, 1.15),
            Encode(),
            Quantize(8),
            ToneLUT(contrast=0.15, gamma=0.95),
        ),
    )


def bayer_jpeg() -> Camera:
    """A cheap Bayer camera that writes JPEG: bilinear demosaicing of a GRBG sensor, JPEG 75 at the end.

    sRGB → linear → lens (Gaussian σ 0.9 px) → colour response (the webcam's filters) → GRBG mosaic → Poisson-Gaussian
    noise (1,200 e⁻, read 0.3 %) → white balance on the mosaic → bilinear demosaic → colour matrix (saturation 1.0)
    → sRGB → 8 bits → JPEG quality 75, 4:2:0 chroma."""
    return Camera(
        "bayer-jpeg",
        (
            Decode(),
            Lens(0.9),
            _raw_response(_WEBCAM_MIX, _WEBCAM_SENSITIVITY),
            Mosaic("GRBG"),
            ShotNoise(1200.0, 0.003),
            MosaicGains((1.0 / 0.52, 1.0, 1.0 / 0.66), "GRBG"),
            Demosaic("bilinear", "GRBG"),
            _colour_correction(_WEBCAM_MIX, 1.0),
            Encode(),
            Quantize(8),
            Jpeg(75, "4:2:0"),
        ),
    )


def zoom_lanczos() -> Camera:
    """A camera that compresses at sensor resolution and zooms afterwards (a video stream shown enlarged).

    sRGB → linear → defocus (disc of radius 0.8 px) → a sensor of half the pixels (PIL Lanczos) → Poisson-Gaussian
    noise (3,000 e⁻, read 0.2 %) → sRGB → 8 bits → JPEG quality 70, 4:2:0, at the sensor's resolution → 2× upscale
    of the decoded 8-bit frame (PIL Lanczos): the JPEG's 8×8 blocks come out 16×16, with Lanczos ringing."""
    return Camera(
        "zoom-lanczos",
        (
            Decode(),
            Defocus(0.8),
            SensorSampling(0.5, "lanczos"),
            ShotNoise(3000.0, 0.002),
            Encode(),
            Quantize(8),
            Jpeg(70, "4:2:0"),
            Zoom("lanczos", eight_bit=True),
        ),
    )


def cheap_nearest() -> Camera:
    """A toy camera: nearest-neighbour subsampling (aliasing), a 6-bit ADC, and web JPEG.

    sRGB → linear → a sensor of half the pixels sampled by PIL nearest (no low-pass: fine detail aliases) →
    Poisson-Gaussian noise (800 e⁻, read 0.4 %) → sRGB → 6 bits → tone (γ 0.9, +20 % contrast) as an 8-bit table →
    2× upscale of the 8-bit buffer (PIL bilinear) → JPEG quality 50, 4:2:0, at the frame's resolution."""
    return Camera(
        "cheap-nearest",
        (
            Decode(),
            SensorSampling(0.5, "nearest"),
            ShotNoise(800.0, 0.004),
            Encode(),
            Quantize(6),
            ToneLUT(contrast=0.2, gamma=0.9),
            Zoom("bilinear", eight_bit=True),
            Jpeg(50, "4:2:0"),
        ),
    )


def gamma_blur() -> Camera:
    """A camera that tones first and blurs in gamma (an ISP's low-pass on encoded values), noise after the blur.

    sRGB → linear → exposure ×1.3 → Poisson-Gaussian noise at the frame's resolution (2,000 e⁻, read 0.2 %) → sRGB
    → 8 bits → contrast S-curve (+30 %) as an 8-bit table → lens-like blur on the *encoded* values (Gaussian σ 0.8 px
    + 6 % halo of σ 3 px) → white read-out noise after the blur (std 0.5 % of full scale) → 8 bits."""
    return Camera(
        "gamma-blur",
        (
            Decode(),
            Exposure(1.3),
            ShotNoise(2000.0, 0.002),
            Encode(),
            Quantize(8),
            ToneLUT(contrast=0.3),
            Lens(0.8, halo_sigma=3.0, halo_weight=0.06),
            WhiteNoise(0.005),
            Quantize(8),
        ),
    )


def shaky_defocus() -> Camera:
    """A handheld camera, slightly misregistered: sub-pixel shift and rotation, defocus and motion in linear light,
    polynomial vignetting, JPEG 90.

    sRGB → shift (0.35, −0.25) px and 0.3° rotation (PIL bicubic) → linear → defocus (disc of radius 1.2 px) →
    motion (3 px at 60°) → vignetting 1 − 0.35 r² + 0.05 r⁴ → Poisson-Gaussian noise (4,000 e⁻, read 0.1 %) → sRGB →
    tone (γ 1.1, black 0.02) on float values → 8 bits → JPEG quality 90, 4:4:4."""
    return Camera(
        "shaky-defocus",
        (
            Misalign(0.35, -0.25, 0.3, "bicubic"),
            Decode(),
            Defocus(1.2),
            Motion(3.0, 60.0),
            PolynomialVignetting(-0.35, 0.05),
            ShotNoise(4000.0, 0.001),
            Encode(),
            ToneCurve(gamma=1.1, black=0.02),
            Quantize(8),
            Jpeg(90, "4:4:4"),
        ),
    )


def noisy_upscale() -> Camera:
    """Noise on both sides of a resize: a sensor of two thirds of the pixels, upscaled, then noise at the frame's
    resolution.

    sRGB → linear → lens (Gaussian σ 0.5 px) → a sensor of 2/3 the pixels (PIL bilinear) → Poisson-Gaussian noise
    (1,500 e⁻, read 0.1 %) → sRGB → 8 bits → upscale to the frame (PIL bicubic, float) → white noise after the resize
    (0.4 % of full scale) and row stripes (0.2 %) → 8 bits → tone (γ 0.85) as an 8-bit table on the 8-bit values."""
    return Camera(
        "noisy-upscale",
        (
            Decode(),
            Lens(0.5),
            SensorSampling(2.0 / 3.0, "bilinear"),
            ShotNoise(1500.0, 0.001),
            Encode(),
            Quantize(8),
            Zoom("bicubic"),
            WhiteNoise(0.004),
            RowNoise(0.002),
            Quantize(8),
            ToneLUT(gamma=0.85),
        ),
    )


def webcam_jpeg25() -> Camera:
    """Issue 42's second hidden camera: the webcam (:func:`webcam`) plus stronger vignetting, white noise at the
    output resolution and JPEG quality 25 at the end (a video call's stream).

    sRGB → linear → polynomial vignetting 1 − 0.3 r² → the webcam's chain (lens, cos⁴ vignetting, a sensor of half
    the pixels, noise, colour, S-curve table, PIL bicubic 2× upscale of the 8-bit buffer) → white noise of 1.5 % of
    full scale on the upscaled frame → 8 bits → JPEG quality 25, 4:2:0."""
    base = webcam()
    stages = list(base.stages)
    stages.insert(1, PolynomialVignetting(-0.3, 0.0))
    stages += [WhiteNoise(0.015), Quantize(8), Jpeg(25, "4:2:0")]
    return Camera("webcam-jpeg25", tuple(stages))


#: Every foreign camera by name (the factory's docstring is its chain).
CAMERAS: dict[str, Callable[[], Camera]] = {
    "webcam": webcam,
    "phone": phone,
    "bayer-jpeg": bayer_jpeg,
    "zoom-lanczos": zoom_lanczos,
    "cheap-nearest": cheap_nearest,
    "gamma-blur": gamma_blur,
    "shaky-defocus": shaky_defocus,
    "noisy-upscale": noisy_upscale,
    "webcam-jpeg25": webcam_jpeg25,
}


def camera(name: str) -> Camera:
    """The foreign camera called ``name`` (one of :data:`CAMERAS`)."""
    if name not in CAMERAS:
        raise ValueError(f"name must be one of {sorted(CAMERAS)}, got name={name!r}")
    return CAMERAS[name]()
