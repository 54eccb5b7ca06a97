"""A fit's first question: does the camera sample fewer pixels than it outputs?

A sensor read at half the resolution and upsampled by the ISP leaves, above the sampled Nyquist frequency, images of
the sampled spectrum locked to the sensor's grid: a pattern no shift-invariant filter reproduces, so a network
trained on such captures smooths it away (a simulated 2× camera: its top band, 0.35–0.5 cycles/pixel, 2.9 log2
short; a critic tells it from the camera at 0.70–0.75). The upscale's trace is read from the training captures
(:func:`~camdegrade.measures.traces.resampling.resampling_trace`); where one is found, the network is trained through a
:class:`~camdegrade.effects.Resolution` stage of that scale, which the profile keeps after it. The unpaired fit asks
the same question of its captures and clean set (:func:`sensor_trace`, :func:`sensor_verdict`) and, having no
network, fits every later stage through the stage it finds.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

from torch import Tensor

from camdegrade.effects import Resolution
from camdegrade.effects.base import evenly_spaced
from camdegrade.fitting.steps.base import FitStep, PairedFit, Verdict
from camdegrade.measures.traces.resampling import ResamplingTrace, resampling_trace
from camdegrade.network import LocalAffineNet

__all__ = ["SENSOR_CAPTURES", "SENSOR_SAMPLING", "SensorResolution", "sensor_trace", "sensor_verdict"]

#: How the sensor stage a fit finds samples: over each pixel's area, as a sensor's pixels integrate light (the
#: network before it decides how much detail reaches it, and what comes through aliases as in the camera). A
#: foreign camera sampled by PIL's box filter shows the 2× grid's phase in its gradient energy, 0.68 : 1.32 on
#: alternate columns; an antialiased reduction left the fitted profile 0.90 : 1.10 (docs/results.md).
SENSOR_SAMPLING = "area"
#: At most this many captures are read (evenly spaced): the coherence is pooled over their rows and columns, and a
#: dozen frames of 128² already separate an upscale from none by more than 0.4.
SENSOR_CAPTURES = 32


@dataclass(frozen=True)
class SensorResolution(FitStep):
    """The resolution step: the sensor stage the network is trained through, at ``scale`` of the output's
    resolution (below 1; 1: none), or ``"auto"``: the scale the training captures show (:func:`sensor_trace`), for
    a ``local_affine`` network trained from its baseline only (a refit continues its network as it was trained).
    The profile keeps the stage after the network, and drops it with the network (its record then says so)."""

    name: ClassVar[str] = "resolution"
    before_network: ClassVar[bool] = True
    scale: str | float = "auto"

    def check(self, recipe: Any) -> None:
        if self.scale != "auto" and self.scale < 1 and recipe.arch != LocalAffineNet.arch:
            raise ValueError(
                f"sensor_scale={self.scale} needs arch='local_affine' (its network is trained through the sensor), "
                f"got arch={recipe.arch!r}"
            )

    def propose(self, fit: PairedFit) -> Resolution | ResamplingTrace | Verdict:
        if self.scale == "auto":
            if fit.arch != LocalAffineNet.arch or fit.refit:
                return Verdict({"kept": False, "reason": "auto: only a local_affine network trained from its baseline"})
            return sensor_trace(
                [clean for clean, _ in fit.train.images], [captured for _, captured in fit.train.images]
            )
        if self.scale >= 1:
            return Verdict({"kept": False, "scale": 1.0})
        # FitConfig and fit_profile refused it with arch='paper' or init_from
        return Resolution(self.scale, sample=SENSOR_SAMPLING)

    def judge(self, fit: PairedFit, proposal: Resolution | ResamplingTrace) -> dict[str, Any]:
        if isinstance(proposal, ResamplingTrace):
            fit.sensor, record = sensor_verdict(proposal, fit.say, then="the network is trained through it")
            return record
        fit.say(
            f"resolution: the network is trained through a sensor at {self.scale:.4g}x (windows every "
            f"{proposal.period} px)"
        )
        fit.sensor = proposal
        return {"kept": True, "scale": round(float(self.scale), 4), "period": proposal.period}


def sensor_trace(cleans: Sequence[Tensor] | None, captures: Sequence[Tensor]) -> ResamplingTrace:
    """The upscale's trace in at most :data:`SENSOR_CAPTURES` of the ``captures`` (evenly spaced), against the same
    of the ``cleans`` (an upscale already in the clean images is not the camera's; ``None``: no clean images, the
    captures' trace alone). The clean images need not be the captures' scenes."""
    reference = None if cleans is None else evenly_spaced(list(cleans), SENSOR_CAPTURES)
    return resampling_trace(evenly_spaced(list(captures), SENSOR_CAPTURES), reference)


def sensor_verdict(
    trace: ResamplingTrace, say: Callable[[str], None], *, then: str
) -> tuple[Resolution | None, dict[str, Any]]:
    """The sensor stage ``trace`` shows (``1/q`` of the captures' resolution where its coherence at period ``q``
    stands above its null and the codec's grid), or ``None``; and its record (``fitted['resolution']``, or an
    unpaired fit's ``fitted['effects']['resolution']``). ``then`` ends the log's line: what the caller does with a
    stage found (an unpaired fit trains no network through it)."""
    shown = ", ".join(f"1/{period} {value:.2f}" for period, value in trace.coherence.items())
    if trace.reference is not None:
        shown += "; clean images " + ", ".join(f"{value:.2f}" for value in trace.reference.values())
    if trace.period is None:
        say(
            f"resolution: no upscale added by the camera in {trace.images} captures (coherence {shown}; "
            f"null {trace.null:.2f}, JPEG grid {trace.codec:.2f})"
        )
        return None, {"kept": False, **trace.to_dict()}
    sensor = Resolution(1.0 / trace.period, sample=SENSOR_SAMPLING)
    say(
        f"resolution: the captures are upscaled from 1/{trace.period} of their resolution (coherence {shown}; "
        f"null {trace.null:.2f}, JPEG grid {trace.codec:.2f}): {then}"
    )
    return sensor, {"kept": True, "scale": round(1.0 / trace.period, 4), **trace.to_dict()}
