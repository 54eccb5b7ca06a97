"""Whether a change to the ISP's resampler (the ``resolution`` stage) names a difference of the resampler itself.

The resampler's statistic in the gap is the transfer function (``frequency``), which every smoothing stage shares: a
refit of its kernel absorbs a defocus as readily as a blur does, and its own statistics agree
(:mod:`camdegrade.diagnose.attribution.signature`). What only a resampler leaves is its trace: an image upscaled from
a sensor of ``1/q`` its pixels is coherent across the frequencies ``f`` and ``f − 1/q``
(:func:`~camdegrade.measures.traces.resampling.resampling_trace`), whatever the kernel and whatever blur came before
the sensor. A change to the resampler names the cause only where that trace says the resampling differs: the period
the captures show is not the one the profile's simulation shows, and the changed profile's simulation shows the
captures' one. Where the simulation already shows the captures' period, the kernel's share of the transfer cannot be
told from a blur's, and the change is not a cause (the candidate whose signature matches, a blur, is named instead).

References:
    A. C. Popescu, H. Farid, "Exposing digital forgeries by detecting traces of resampling", IEEE Trans. Signal
    Processing 53(2), 2005.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from camdegrade.measures.traces.resampling import resampling_trace

if TYPE_CHECKING:
    from camdegrade.diagnose.attribution.changes import Change
    from camdegrade.diagnose.attribution.round_view import Round
    from camdegrade.diagnose.heldout import HeldOut
    from camdegrade.profile import CameraProfile

__all__ = ["RESAMPLER", "resampler_unsupported", "simulated_period"]

#: The stage that resamples the frame (the only one whose own trace is measured).
RESAMPLER = "resolution"


def simulated_period(held: HeldOut, profile: CameraProfile) -> int | None:
    """The upscale period the resampling trace finds in ``profile``'s simulation of the held-out pairs (None: none),
    the clean images as the reference (as for the captures)."""
    sims = profile.simulate(held.cleans, held.seed, stream=held.stream)
    return resampling_trace(sims, held.cleans).period


def resampler_unsupported(change: Change, round_: Round) -> str:
    """Why ``change`` (to the resampler) is not a cause by its trace, in words; empty when it is not a change to the
    resampler or its trace supports it (see the module)."""
    if change.name != RESAMPLER or change.kind not in ("add", "refit", "remove") or change.profile is None:
        return ""
    held = round_.search.held
    real = held.real_period
    before = simulated_period(held, round_.current)
    after = simulated_period(held, change.profile)
    if before != real and after == real:
        return ""
    said = {None: "none"}
    return (
        f"not a cause: the resampling trace finds period {said.get(real, real)} in the captures and "
        f"{said.get(before, before)} in the simulation before the change, {said.get(after, after)} after: the "
        "resampling itself does not differ, and its share of the transfer function is any smoothing's"
    )
