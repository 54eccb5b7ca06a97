"""The unpaired fit's sensor: the resolution step (an upscale whose periodic trace the captures show, or a scale
given) and the options that choose how the sensor is searched (``sensor_scale``, ``area_sensor``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any, ClassVar

from camdegrade.effects import Effect, Resolution
from camdegrade.fitting.steps.base import Verdict
from camdegrade.fitting.steps.resolution import sensor_trace, sensor_verdict
from camdegrade.fitting.unpaired.bench import UnpairedFit, UnpairedStep
from camdegrade.fitting.unpaired.steps.area_sensor import AreaSensorMatch
from camdegrade.measures.traces.resampling import ResamplingTrace

__all__ = ["SensorStep", "check_area_sensor", "check_sensor_scale", "with_sensor"]


@dataclass(frozen=True)
class SensorStep(UnpairedStep):
    """The resolution step, first so every later stage is fitted through it: an upscale the captures show and the
    clean set does not (:func:`~camdegrade.fitting.steps.resolution.sensor_trace`; without a clean set, the
    captures' trace alone), judged against the trace's null and the codec's grid; or the ``scale`` given."""

    name: ClassVar[str] = "resolution"
    kinds: ClassVar[tuple[type[Effect], ...]] = (Resolution,)
    scale: float | None = None

    def propose(self, fit: UnpairedFit) -> ResamplingTrace | Verdict:
        if self.scale is not None:  # given: kept as it is, below 1
            fit.keep(Resolution(self.scale) if self.scale < 1 else None)
            return Verdict({"kept": self.scale < 1, "scale": self.scale, "given": True})
        return sensor_trace(fit.cleans.images if fit.cleans else None, fit.captures.images)

    def judge(self, fit: UnpairedFit, trace: ResamplingTrace) -> dict[str, Any]:
        then = "every later stage is fitted through it (the profile has no network)"
        stage, record = sensor_verdict(trace, fit.say, then=then)
        fit.keep(stage)
        return record


def check_sensor_scale(value: Any) -> float | None:
    """``sensor_scale`` as a number, or ``None`` for ``"auto"``; a ``ValueError`` for anything else."""
    number = not isinstance(value, bool) and isinstance(value, (int, float))
    if value == "auto":
        return None
    if not (number and Resolution.MIN_SCALE <= value <= 1):
        raise ValueError(
            f"sensor_scale must be 'auto' or a number from {Resolution.MIN_SCALE} to 1, got sensor_scale={value!r}"
        )
    return float(value)


def check_area_sensor(value: Any) -> bool:
    """``area_sensor`` as it is; a ``TypeError`` for anything but a bool."""
    if not isinstance(value, bool):
        raise TypeError(f"area_sensor must be a bool, got area_sensor={value!r} ({type(value).__name__})")
    return value


def with_sensor(
    steps: Sequence[tuple[str, UnpairedStep]], scale: float | None, area_sensor: bool
) -> list[tuple[str, UnpairedStep]]:
    """``steps`` with the resolution step's ``scale`` (``None``: found from the captures) and the area-sensor
    step searching only where ``area_sensor`` asks for it."""

    def configured(step: UnpairedStep) -> UnpairedStep:
        if isinstance(step, SensorStep):
            return replace(step, scale=scale)
        return replace(step, search=area_sensor) if isinstance(step, AreaSensorMatch) else step

    return [(label, configured(step)) for label, step in steps]
