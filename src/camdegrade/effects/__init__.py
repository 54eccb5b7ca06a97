"""Camera effects: one ``nn.Module`` per effect, registered by name in :data:`EFFECTS`.

The registered names are the diagnosis vocabulary; each effect sits at a stage of a camera (optics → sensor → ISP
→ codec) and has a ``fit(source, target)`` classmethod that estimates it from aligned pairs. The contract every
effect follows is in :mod:`camdegrade.effects.base`; ``docs/effects.md`` describes each one.
"""

from camdegrade.effects.base import (
    EFFECTS,
    STAGES,
    Effect,
    Pairs,
    build_effect,
    check_effect_names,
    register_effect,
)

# The registry's order is the order of these imports (every vocabulary listing and report follows it): keep it,
# and add a new effect at the end.
# isort: off
from camdegrade.effects.optics.blur import Blur
from camdegrade.effects.codec.jpeg import JPEG
from camdegrade.effects.isp.color import Color, Tone
from camdegrade.effects.isp.denoise import Denoise
from camdegrade.effects.optics.geometry import ChromaticAberration, Distortion, Misalignment, Vignetting
from camdegrade.effects.codec.learned_texture import LearnedTexture
from camdegrade.effects.sensor.noise import Noise
from camdegrade.effects.isp.resolution import Resolution
from camdegrade.effects.isp.response import FrequencyResponse
from camdegrade.effects.isp.sharpen import Sharpen
from camdegrade.effects.sensor.cfa import ColorFilterArray
from camdegrade.effects.isp.quantization import Quantization
from camdegrade.effects.optics.jitter import Jitter
# isort: on

__all__ = [
    "EFFECTS",
    "JPEG",
    "STAGES",
    "Blur",
    "ChromaticAberration",
    "Color",
    "ColorFilterArray",
    "Denoise",
    "Distortion",
    "Effect",
    "FrequencyResponse",
    "Jitter",
    "LearnedTexture",
    "Misalignment",
    "Noise",
    "Pairs",
    "Quantization",
    "Resolution",
    "Sharpen",
    "Tone",
    "Vignetting",
    "build_effect",
    "check_effect_names",
    "register_effect",
]
