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
from camdegrade.effects.blur import Blur
from camdegrade.effects.cfa import ColorFilterArray
from camdegrade.effects.codec import JPEG
from camdegrade.effects.color import Color, Tone
from camdegrade.effects.denoise import Denoise
from camdegrade.effects.geometry import ChromaticAberration, Distortion, Misalignment, Vignetting
from camdegrade.effects.learned_texture import LearnedTexture
from camdegrade.effects.noise import Noise
from camdegrade.effects.quantization import Quantization
from camdegrade.effects.resolution import Resolution
from camdegrade.effects.response import FrequencyResponse
from camdegrade.effects.sharpen import Sharpen

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
