"""A fit's first question: does the camera sample fewer pixels than it outputs?

A sensor read at half the resolution and upsampled by the ISP leaves, above the sampled Nyquist frequency, images of
the sampled spectrum locked to the sensor's grid: a pattern no shift-invariant filter reproduces, so a network
trained on such captures smooths it away (a simulated 2× camera: its top band, 0.35–0.5 cycles/pixel, 2.9 log2
short; a critic tells it from the camera at 0.70–0.75). The upscale's trace is read from the training captures
(:func:`~camdegrade.measures.traces.resampling.resampling_trace`); where one is found, the network is trained through a
:class:`~camdegrade.effects.Resolution` stage of that scale, which the profile keeps after it. The unpaired fit asks
the same question of its captures and clean set (:func:`sensor_trace`, :func:`sensor_verdict`) and, having no
network, fits every later stage through the stage it finds.

The ISP's kernel (the resampler step, :class:`ResamplerKernel`): the stage's ``upsample``, chosen in the profile as
it stands after the effect stages (noise, codec), by the grid's phase in the gradient energy
(:func:`~camdegrade.measures.traces.grid_phase.grid_phase_energy`). The network is trained through a stage of
torch's cubic; which kernel the camera used shows in how strongly alternate pixels differ, most in its noise, which
the network cannot shape. Read on the pairs the fit judges on, every kernel in turn in the sampled profile: the
kernel whose pattern comes nearest the captures' replaces the stage's where it is nearer by more than
:data:`SIGNIFICANCE` times the pattern's own spread over the images. Read here rather than on the captures' flat
pixels alone: a codec after the upscale weakens the pattern (a foreign camera's bilinear zoom under JPEG 50 reads
as Lanczos there), and the profile's own codec stage does so too.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

from torch import Tensor

from camdegrade.effects import Resolution
from camdegrade.effects.base import evenly_spaced
from camdegrade.fitting.steps.base import FitStep, PairedFit, Verdict
from camdegrade.fitting.steps.noise_evidence import as_stored
from camdegrade.functional.sensor.resolution import UPSAMPLERS
from camdegrade.measures.traces.grid_phase import grid_phase_energy, grid_phase_spread
from camdegrade.measures.traces.resampling import ResamplingTrace, resampling_trace
from camdegrade.network import LocalAffineNet
from camdegrade.profile import CameraProfile

__all__ = [
    "RESAMPLER_PAIRS",
    "SENSOR_CAPTURES",
    "SENSOR_SAMPLING",
    "SIGNIFICANCE",
    "ResamplerKernel",
    "SensorResolution",
    "sensor_trace",
    "sensor_verdict",
    "with_upsampler",
]

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


#: At most this many of the judged pairs are simulated per kernel.
RESAMPLER_PAIRS = 16
#: A kernel replaces the stage's where its pattern is nearer the captures' by this many times the pattern's spread.
SIGNIFICANCE = 3.0


def with_upsampler(profile: CameraProfile, kernel: str) -> CameraProfile:
    """``profile`` with its resolution stages upsampling by ``kernel`` (scale and sampling kept)."""
    chain = [
        Resolution(float(stage.scale), kernel, stage.sample) if isinstance(stage, Resolution) else stage
        for stage in profile.effects
    ]
    return profile.with_chain(chain)


@dataclass(frozen=True)
class ResamplerKernel(FitStep):
    """The resampler step: the resolution stage's upsampling kernel, chosen by the grid's phase (see the module);
    recorded in ``fitted['resampler']``."""

    name: ClassVar[str] = "resampler"

    def propose(self, fit: PairedFit) -> tuple[Resolution, list, str] | Verdict:
        stage = next((effect for effect in fit.profile.effects if isinstance(effect, Resolution)), None)
        if stage is None:
            return Verdict({"kept": False, "reason": "the profile has no resolution stage"})
        pairs, label = fit.evidence_pairs
        return stage, list(pairs)[:RESAMPLER_PAIRS], label

    def judge(self, fit: PairedFit, proposal: tuple[Resolution, list, str]) -> dict[str, Any]:
        stage, pairs, label = proposal
        period = stage.period
        captures = [captured for _, captured in pairs]
        real = grid_phase_energy(captures, period)
        spread = grid_phase_spread(captures, period)
        cleans = [clean for clean, _ in pairs]
        distances = {}
        for kernel in UPSAMPLERS:
            sampled = with_upsampler(fit.profile, kernel).simulate(cleans, fit.seed, stream="resampler")
            distances[kernel] = float(
                (grid_phase_energy(as_stored(sampled, fit.eight_bit), period) - real).abs().mean()
            )
        best = min(distances, key=distances.__getitem__)
        gain = distances[stage.upsample] - distances[best]
        kept = best != stage.upsample and gain > SIGNIFICANCE * spread
        if kept:
            fit.profile = with_upsampler(fit.profile, best)
        chosen = best if kept else stage.upsample
        fit.say(
            f"resampler: {chosen} ({'replaces ' + stage.upsample if kept else 'kept'}): the grid's phase in the "
            f"{label} captures {_shown(real[0])}, simulated {stage.upsample} {distances[stage.upsample]:.3f} from it, "
            f"{best} {distances[best]:.3f} (spread {spread:.3f}, {len(pairs)} pairs)"
        )
        return {
            "kept": kept,
            "upsample": chosen,
            "evidence": label,
            "period": period,
            "captures": [round(float(value), 4) for value in real.flatten()],
            "distances": {kernel: round(value, 4) for kernel, value in distances.items()},
            "spread": round(spread, 4),
        }


def _shown(row: Any) -> str:
    return " : ".join(f"{float(value):.2f}" for value in row)
