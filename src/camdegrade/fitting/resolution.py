"""A fit's first question: does the camera sample fewer pixels than it outputs?

A sensor read at half the resolution and upsampled by the ISP leaves, above the sampled Nyquist frequency, images of
the sampled spectrum locked to the sensor's grid: a pattern no shift-invariant filter reproduces, so a network
trained on such captures smooths it away (a simulated 2× camera: its top band, 0.35–0.5 cycles/pixel, 2.9 log2
short; a critic tells it from the camera at 0.70–0.75). The upscale's trace is read from the training captures
(:func:`~camdegrade.measures.resampling.resampling_trace`); where one is found, a paired fit trains its network
through a :class:`~camdegrade.effects.Resolution` stage of that scale, which the profile keeps after it, and an
unpaired fit (no network) fits every later stage through it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from torch import Tensor

from camdegrade.effects import Resolution
from camdegrade.effects.base import evenly_spaced
from camdegrade.measures.resampling import resampling_trace

#: At most this many captures are read (evenly spaced): the coherence is pooled over their rows and columns, and a
#: dozen frames of 128² already separate an upscale from none by more than 0.4.
SENSOR_CAPTURES = 32


def find_sensor(
    cleans: Sequence[Tensor] | None, captures: Sequence[Tensor], say: Callable[[str], None], *, then: str
) -> tuple[Resolution | None, dict[str, Any]]:
    """The sensor stage the ``captures`` show (``1/q`` of their resolution) and the ``cleans`` do not (an upscale
    already in the clean images is not the camera's; ``None``: no clean images, the captures' trace alone), or
    ``None``; and the note for ``fitted['resolution']`` (or an unpaired fit's ``fitted['effects']['resolution']``).
    The clean images need not be the captures' scenes; ``then`` says on the log what the caller does with a stage
    found (a fit without a network trains none through it)."""
    reference = None if cleans is None else evenly_spaced(list(cleans), SENSOR_CAPTURES)
    trace = resampling_trace(evenly_spaced(list(captures), SENSOR_CAPTURES), reference)
    shown = ", ".join(f"1/{period} {value:.2f}" for period, value in trace.coherence.items())
    if trace.reference is not None:
        shown += "; clean images " + ", ".join(f"{value:.2f}" for value in trace.reference.values())
    if trace.period is None:
        say(
            f"resolution: no upscale added by the camera in {trace.images} captures (coherence {shown}; "
            f"null {trace.null:.2f}, JPEG grid {trace.codec:.2f})"
        )
        return None, {"kept": False, **trace.to_dict()}
    sensor = Resolution(1.0 / trace.period)
    say(
        f"resolution: the captures are upscaled from 1/{trace.period} of their resolution (coherence {shown}; "
        f"null {trace.null:.2f}, JPEG grid {trace.codec:.2f}): {then}"
    )
    return sensor, {"kept": True, "scale": round(1.0 / trace.period, 4), **trace.to_dict()}
