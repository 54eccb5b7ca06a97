"""A Bayer mosaic's trace in images read alone: whether a demosaic made them, and of which layout.

A demosaic keeps each colour where the sensor sampled it and interpolates it elsewhere, so red less green and blue
less green are nearly the mean of their neighbours where red (blue) was not sampled, and noise drawn per site before
the demosaic is averaged there too; red and blue are sampled at different phases of the 2×2 grid
(:func:`mosaic_trace`: the **colour** route). A resampler, a JPEG grid or a readout pattern leaves one phase pattern
in every channel, which the colour route reads as 1. A JPEG with 4:2:0 chroma averages red and blue less luma over
each 2×2 tile and leaves only luma's trace (:func:`luma_trace`: the **luma** route): luma holds 0.114 of a sampled
colour at blue's site, 0.299 at red's, 0.587 at green's, so a mosaic leaves the least energy at blue's site (red's
and green's order varies with the demosaic and the colour matrix). A pattern common to all channels can do so too
(real cameras' captures and clean images alike: CC15 0.71 and 0.80; a noisy bilinear upscale 0.94), so the luma route
proposes by the phases' form, not by that ratio's size (:mod:`camdegrade.measures.traces.mosaic_form`: a diagonal
contrast a pattern of rows times columns has not, the two green sites alike), with blue's site the least, and the
clean images without that form.

Both read clean images and captures alike: clean images with a mosaic of their own get no second one
(:func:`read_mosaic`). Values on cameras and real pairs: docs/results.md, *A colour filter array among the default
stages*.

References:
    A. C. Popescu, H. Farid, "Exposing digital forgeries in color filter array interpolated images", IEEE Trans.
    Signal Processing 53(10), 2005 (the periodic trace of interpolation).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from camdegrade.functional.sensor.cfa import (
    PATTERNS,
    bayer_masks,
    colour_phase_share,
    interpolation_phases,
    luma_phases,
)
from camdegrade.measures.traces.mosaic_form import MosaicForm, form_margin, greens_alike, read_form

__all__ = ["MAX_TRACE", "ROUTES", "MosaicReading", "luma_order", "luma_trace", "mosaic_trace", "read_mosaic"]

#: The colour route proposes a layout whose captures' trace is at most this, where the clean images' is above it (a
#: phone's Hamilton–Adams mosaic 0.4; cameras without one and real pairs 0.95–1.0).
MAX_TRACE = 0.85


def mosaic_trace(images: Sequence[Tensor], pattern: str) -> float:
    """The colour route's trace of a mosaic of ``pattern`` in ``images`` (``(3, H, W)`` each): the reciprocal of
    :func:`~camdegrade.functional.sensor.cfa.colour_phase_share` of their mean
    :func:`~camdegrade.functional.sensor.cfa.interpolation_phases` (below 1 where they hold one; 1 without; the
    reciprocal for the layout with red and blue swapped)."""
    phases = sum(interpolation_phases(image) for image in images) / len(images)
    return 1.0 / max(colour_phase_share(phases, pattern), 1e-12)


def _luma_sites(phases: Tensor, pattern: str) -> tuple[float, float, float]:
    """``(blue, red, least green)`` of a luma ``(2, 2)`` at ``pattern``'s sites."""
    masks = bayer_masks(2, 2, pattern).bool()
    return float(phases[masks[2]][0]), float(phases[masks[0]][0]), float(phases[masks[1]].min())


def _mean_luma(images: Sequence[Tensor]) -> Tensor:
    return torch.stack([luma_phases(image) for image in images]).mean(0)


def luma_trace(images: Sequence[Tensor], pattern: str) -> float:
    """The luma route's trace: of the mean :func:`~camdegrade.functional.sensor.cfa.luma_phases` of ``images``, the
    phase where ``pattern`` samples blue over the one where it samples red (below 1 for a mosaic of ``pattern``)."""
    return _ratio(_mean_luma(images), pattern)


def luma_order(images: Sequence[Tensor], pattern: str) -> bool:
    """Whether the luma phases of ``images`` are ordered as a mosaic of ``pattern`` leaves them: least where it samples
    blue, the two green sites nearer each other than red's and blue's."""
    return _ordered(_mean_luma(images), pattern)


#: The routes' traces by name.
ROUTES: dict[str, Callable[[Sequence[Tensor], str], float]] = {"colour": mosaic_trace, "luma": luma_trace}


@dataclass(frozen=True)
class MosaicReading:
    """What a set of pairs shows of a mosaic, by one route: the layout whose trace in the captures is least, every
    layout's trace there, the clean images' trace at that layout, and (luma) the captures' mosaic form
    (:class:`~camdegrade.measures.traces.mosaic_form.MosaicForm`), whether their phases come in a mosaic's order
    (blue's site the least, the green sites alike) and whether the clean images' phases hold that form."""

    route: str
    pattern: str
    traces: dict[str, float]
    cleans_trace: float
    form: MosaicForm | None = None
    ordered: bool | None = None
    cleans_form: bool | None = None

    @property
    def trace(self) -> float:
        return self.traces[self.pattern]

    def proposed(self) -> bool:
        """Colour: the captures' trace at most :data:`MAX_TRACE`, the clean images' above it. Luma: the captures'
        phases in a mosaic's order and form (its bootstrap bound above 0), the clean images' without that form."""
        if self.route == "colour":
            return self.trace <= MAX_TRACE < self.cleans_trace
        return bool(self.ordered) and self.form is not None and self.form.held and not self.cleans_form

    def to_dict(self) -> dict[str, Any]:
        note = {
            "route": self.route,
            "pattern": self.pattern,
            "captures_trace": round(self.trace, 3),
            "captures_traces": {layout: round(value, 3) for layout, value in self.traces.items()},
            "cleans_trace": round(self.cleans_trace, 3),
        }
        if self.route == "luma" and self.form is not None:
            note |= {
                "form_margin": round(self.form.margin, 4),
                "form_bound": round(self.form.bound, 4),
                "form_ratio": round(self.form.ratio, 3),
                "ordered": self.ordered,
                "cleans_form": self.cleans_form,
            }
        return note


def read_mosaic(cleans: Sequence[Tensor], captures: Sequence[Tensor], generator: torch.Generator) -> MosaicReading:
    """The colour route's reading of ``captures`` and their clean images where it proposes a layout or the clean
    images alone stop it; else the luma route's (``generator`` draws its bootstrap)."""
    traces = {pattern: mosaic_trace(captures, pattern) for pattern in PATTERNS}
    pattern = min(PATTERNS, key=traces.__getitem__)
    colour = MosaicReading("colour", pattern, traces, mosaic_trace(cleans, pattern))
    if colour.trace <= MAX_TRACE:
        return colour
    return _luma_reading(cleans, captures, generator)


def _luma_reading(cleans: Sequence[Tensor], captures: Sequence[Tensor], generator: torch.Generator) -> MosaicReading:
    """The luma route's reading: the layout of least trace among those whose order the captures' phases have (all,
    where none has), the captures' form (its bound over images drawn with replacement by ``generator``) and whether
    the clean images' mean phases hold that form."""
    per_image = torch.stack([luma_phases(image) for image in captures])
    phases = per_image.mean(0)
    traces = {pattern: _ratio(phases, pattern) for pattern in PATTERNS}
    ordered = [pattern for pattern in PATTERNS if _ordered(phases, pattern)]
    pattern = min(ordered or PATTERNS, key=traces.__getitem__)
    clean = _mean_luma(cleans)
    cleans_form = form_margin(clean) > 0 and _ordered(clean, pattern)
    form = read_form(per_image, generator)
    return MosaicReading("luma", pattern, traces, _ratio(clean, pattern), form, bool(ordered), cleans_form)


def _ratio(phases: Tensor, pattern: str) -> float:
    blue, red, _ = _luma_sites(phases, pattern)
    return blue / max(red, 1e-12)


def _ordered(phases: Tensor, pattern: str) -> bool:
    blue, red, green = _luma_sites(phases, pattern)
    return blue < min(red, green) and greens_alike(phases, pattern)
