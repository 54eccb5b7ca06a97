"""The unpaired fit's own check as a gate (issue 43, item 2): the statistics the fit matched, read once more on its
result (``quality["unpaired_fidelity"]``: the clean set simulated through the fitted chain against the captures,
with seeds of their own), and a warning where they say the result is off. ``strict`` refuses such a result.

The check reads the same images the stages were fitted on (an unpaired fit has no held-out pairs; each stage was
already kept only where random halves of the sets agreed), so it cannot say that a profile is right, only that it
is wrong: a noise ratio far from 1 or a band far off is a result that does not even reproduce what it was fitted
to (the real PolyU captures of issue 43, before the smooth noise curve: noise ratio 1.79 with 16–20-level speckle
on flat greys)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

#: The flat-noise ratio (simulated over the captures') must lie in this range ...
NOISE_RATIO_GATE = (0.67, 1.5)
#: ... and every band's log2 power difference within this (only with a clean set: without one the simulation runs
#: on the captures smoothed, whose top bands are the smoothing's).
BAND_GATE_LOG2 = 1.0
#: The stages that set each statistic: a statistic is gated only when the fit was asked for one of them.
NOISE_STAGES = ("noise",)
DETAIL_STAGES = ("blur", "sharpen", "frequency_response")


def self_check_warnings(fidelity: Mapping[str, Any], wanted: Sequence[str], *, with_clean: bool) -> list[str]:
    """The warnings the fit's own check gives (none where it passes), each with its numbers; ``wanted``: the stages
    the fit was asked for."""
    out = []
    low, high = NOISE_RATIO_GATE
    ratio = fidelity.get("noise_ratio")
    if any(name in wanted for name in NOISE_STAGES) and ratio is not None and not low <= ratio <= high:
        out.append(
            f"the fit's own check: the simulated clean set's flat-pixel noise is {ratio:.2f}× the captures' "
            f"(outside {low}–{high}); the noise stage does not reproduce the captures' noise"
        )
    edges = fidelity.get("band_edges", [])
    off = [
        f"{edges[index]:g}–{edges[index + 1]:g} cycles/pixel {value:+.2f}"
        for index, value in enumerate(fidelity.get("bands", []))
        if abs(value) > BAND_GATE_LOG2 and index + 1 < len(edges)
    ]
    if with_clean and any(name in wanted for name in DETAIL_STAGES) and off:
        out.append(
            f"the fit's own check: band power of the simulated clean set against the captures beyond "
            f"±{BAND_GATE_LOG2:g} log2 ({', '.join(off)}); the captures' detail is not reproduced"
        )
    return out
