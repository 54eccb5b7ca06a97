"""Withheld-effect scenarios: a base camera plus ONE effect it lacks, at the place in the chain where a real camera
has it. A profile fitted on the base's pairs is diagnosed on the scenario's pairs; the diagnosis should name the
added effect. Each base also has a control (nothing added), on which it should accept nothing.

``expected`` lists the diagnosis changes that name the added cause (camdegrade's vocabulary: ``"add blur"``, ...);
a refit of a stage that is not the cause's (``refit resolution`` for a defocus) does not count. ``"add quantization"``
is not in today's vocabulary (issue 42, item 2): that scenario cannot be right until it is.
"""

from __future__ import annotations

from dataclasses import dataclass

from foreign_cameras.cameras import Camera, camera
from foreign_cameras.stages import (
    ColorMatrix,
    Defocus,
    Exposure,
    Jpeg,
    Misalign,
    Motion,
    PolynomialVignetting,
    Quantize,
    Sharpen,
    Stage,
    WhiteNoise,
)

#: A warm white-balance error in linear light: red +18 %, blue −20 %.
_WARM_CAST = ((1.18, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 0.8))
#: The two bases: one with a resampling stage (a sensor of half the pixels, zoomed back), one with a Bayer CFA.
BASES = ("webcam", "phone")
#: Bases the diagnosis rules were NOT designed on, to check them on (issue 42): a third resampling camera with noise on
#: both sides of its resize and a tone table after it (``noisy-upscale``).
CHECK_BASES = ("noisy-upscale",)


@dataclass(frozen=True)
class Scenario:
    """``base`` with ``stage`` inserted ``before`` (or ``after``) the first stage of that class (neither: at the
    end); ``stage`` None is the control. ``expected``: the diagnosis changes that name the cause."""

    base: str
    name: str
    stage: Stage | None
    expected: tuple[str, ...]
    before: str | None = None
    after: str | None = None

    def camera(self) -> Camera:
        base = camera(self.base)
        if self.stage is None:
            return base
        return base.inserted(self.stage, before=self.before, after=self.after, name=f"{self.base}/{self.name}")


def _either(effect: str) -> tuple[str, ...]:
    return (f"add {effect}", f"refit {effect}")


def _withheld(base: str, end_of_resampling: str) -> dict[str, Scenario]:
    """The ten withheld effects on ``base``; ``end_of_resampling``: the class after which the frame is at its
    output resolution (where strong noise and sharpening are added)."""
    rows = [
        # Strong white noise after the resize (or the demosaic): an analog link or a second gain stage.
        ("noise-after", WhiteNoise(0.035), _either("noise"), None, end_of_resampling),
        ("defocus", Defocus(2.0), _either("blur"), None, "Decode"),
        ("motion", Motion(6.0, 30.0), _either("blur"), None, "Decode"),
        ("misalignment", Misalign(0.7, -0.5, 0.4, "bicubic"), _either("misalignment"), "Decode", None),
        # One stop under: a brightness change, which the tone curve or a colour matrix (k·I in linear) both name.
        ("exposure", Exposure(0.5), (*_either("tone"), *_either("color")), "ShotNoise", None),
        ("colour-cast", ColorMatrix(_WARM_CAST), _either("color"), "Encode", None),
        ("vignetting", PolynomialVignetting(-0.45), _either("vignetting"), None, "Decode"),
        ("jpeg", Jpeg(40, "4:2:0"), _either("jpeg"), None, None),
        # A 5-bit buffer before the tone table: posterised gradients (banding).
        ("quantization", Quantize(5), ("add quantization",), "ToneLUT", None),
        ("sharpen", Sharpen(1.0, 1.0), _either("sharpen"), None, end_of_resampling),
    ]
    scenarios = {
        name: Scenario(base, name, stage, expected, before, after) for name, stage, expected, before, after in rows
    }
    return {"control": Scenario(base, "control", None, ()), **scenarios}


#: Every scenario, by base and name (``SCENARIOS["webcam"]["defocus"]``); the control first.
SCENARIOS: dict[str, dict[str, Scenario]] = {
    "webcam": _withheld("webcam", "Zoom"),
    "phone": _withheld("phone", "ToneLUT"),
    "noisy-upscale": _withheld("noisy-upscale", "Zoom"),
}
