"""Camera effects: one ``nn.Module`` per effect, registered by name in :data:`EFFECTS`.

The registered names are the diagnosis vocabulary, in physical order of their stages (optics → sensor → ISP →
codec): ``misalignment``, ``distortion``, ``chromatic_aberration``, ``vignetting``, ``blur`` (optics),
``noise`` (sensor), ``color``, ``tone`` (ISP) and ``jpeg`` (codec). Each has a ``fit(source, target)``
classmethod that estimates it from aligned pairs.
"""

from camdegrade.effects._noise_levels import NoiseLevels, noise_level_function
from camdegrade.effects.base import EFFECTS, SIGNATURES, STAGES, Effect, Pairs, build_effect, register_effect
from camdegrade.effects.blur import Blur
from camdegrade.effects.codec import JPEG
from camdegrade.effects.color import Color, Tone
from camdegrade.effects.geometry import ChromaticAberration, Distortion, Misalignment, Vignetting
from camdegrade.effects.noise import Noise

__all__ = [
    "EFFECTS",
    "JPEG",
    "SIGNATURES",
    "STAGES",
    "Blur",
    "ChromaticAberration",
    "Color",
    "Distortion",
    "Effect",
    "Misalignment",
    "Noise",
    "NoiseLevels",
    "Pairs",
    "Tone",
    "Vignetting",
    "build_effect",
    "noise_level_function",
    "register_effect",
]
