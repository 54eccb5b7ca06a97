"""Which kernel the camera's ISP upsamples its sensor with: the :class:`~camdegrade.effects.Resolution` stage's
``upsample``, chosen in the profile as it stands after the effect stages (noise, codec), by the grid's phase in the
gradient energy (:func:`~camdegrade.measures.traces.grid_phase.grid_phase_energy`).

The resolution step finds the sensor's scale from the captures' trace, and the network is trained through a stage
of torch's cubic; which kernel the camera used shows in how strongly alternate pixels differ, most in its noise,
which the network cannot shape. Read on the pairs the fit judges on, every kernel in turn in the sampled profile: the
kernel whose pattern comes nearest the captures' replaces the stage's where it is nearer by more than
:data:`SIGNIFICANCE` times the pattern's own spread over the images. Read here rather than on the captures' flat
pixels alone: a codec after the upscale weakens the pattern (a foreign camera's bilinear zoom under JPEG 50 reads
as Lanczos there), and the profile's own codec stage does so too.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from camdegrade.effects import Resolution
from camdegrade.fitting.steps.base import FitStep, PairedFit, Verdict
from camdegrade.fitting.steps.noise_evidence import as_stored
from camdegrade.functional.sensor.resolution import UPSAMPLERS
from camdegrade.measures.traces.grid_phase import grid_phase_energy, grid_phase_spread
from camdegrade.profile import CameraProfile

__all__ = ["RESAMPLER_PAIRS", "SIGNIFICANCE", "ResamplerKernel", "with_upsampler"]

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
