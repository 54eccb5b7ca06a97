"""The unpaired fit's judges. The captures and the clean set show *different* scenes, so their set statistics differ
by content too: a stage is kept only where the change it makes exceeds both a floor and what the content alone moves
it by, the standard error from random half-splits of both sets (:func:`split_half_error`).

And the fit's own check as a gate (issue 43, item 2; :func:`self_check_warnings`): the statistics the fit matched,
read once more on its result (``quality["unpaired_fidelity"]``: the clean set simulated through the fitted chain
against the captures, with seeds of their own), and a warning where they say the result is off. ``strict`` refuses
such a result. The check reads the same images the stages were fitted on (an unpaired fit has no held-out pairs;
each stage was already kept only where random halves of the sets agreed), so it cannot say that a profile is right,
only that it is wrong: a noise ratio far from 1 or a band far off is a result that does not even reproduce what it
was fitted to (the real PolyU captures of issue 43, before the smooth noise curve: noise ratio 1.79 with 16–20-level
speckle on flat greys). Each band's reading carries its split-half spread (:func:`band_spread`); a band the sets'
content alone moves past the gate is neither warned of nor passed but named in a note (:func:`unmeasured_bands`).
A fresh image-only critic (:func:`self_check_critic`: never a critic any stage was trained
against) says what a model trained on the simulation would see; above
:data:`~camdegrade.fitting.critic_warning.CRITIC_WARNING_ACCURACY` the fit warns. Where the clean set's scenes differ
in kind from the captures' (indoor against outdoor, say), the critic may read that content as well: the warning says
so."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import torch
from torch import Tensor

from camdegrade._support.seeds import derived_generator
from camdegrade.effects.base import evenly_spaced
from camdegrade.fitting.critic_warning import CRITIC_WARNING_ACCURACY
from camdegrade.measures.critic import PATCH, repeated_critic_test

__all__ = [
    "CRITIC_IMAGES",
    "MIN_CRITIC_IMAGES",
    "SIGNIFICANCE",
    "SPLITS",
    "band_spread",
    "common_crops",
    "self_check_critic",
    "self_check_warnings",
    "significant",
    "split_half_error",
    "unmeasured_bands",
]

#: Random half-splits behind a standard error, and how many of them a kept change must exceed.
SPLITS = 8
SIGNIFICANCE = 3.0


def split_half_error(
    estimate: Callable[[list[int], list[int]], Tensor], captures: int, cleans: int, seed: int
) -> Tensor:
    """The standard error of ``estimate(capture indices, clean indices)`` over the whole sets, from
    :data:`SPLITS` random half-splits of both: RMS of half the difference of the two halves' estimates (each half
    has twice the full set's variance). What the content of the images alone moves the estimate by."""
    generator = derived_generator(seed, "unpaired-split")
    halves = []
    for _ in range(SPLITS):
        a, b = (
            torch.randperm(captures, generator=generator).tolist(),
            torch.randperm(cleans, generator=generator).tolist(),
        )
        first = estimate(a[: captures // 2], b[: cleans // 2])
        second = estimate(a[captures // 2 :], b[cleans // 2 :])
        halves.append((first - second) / 2)
    return torch.stack(halves).pow(2).mean(0).sqrt()


def significant(change: Tensor, error: Tensor, floor: float) -> bool:
    """Whether some component of ``change`` exceeds both ``floor`` and :data:`SIGNIFICANCE` standard errors."""
    return bool((change.abs() > torch.clamp(SIGNIFICANCE * error, min=floor)).any())


#: The flat-noise ratio (simulated over the captures') must lie in this range ...
NOISE_RATIO_GATE = (0.67, 1.5)
#: ... and every band's log2 power difference within this (only with a clean set: without one the simulation runs
#: on the captures smoothed, whose top bands are the smoothing's).
BAND_GATE_LOG2 = 1.0
#: The stages that set each statistic: a statistic is gated only when the fit was asked for one of them.
NOISE_STAGES = ("noise",)
DETAIL_STAGES = ("blur", "sharpen", "frequency_response")


#: The self-check's critic: at most this many clean images and as many captures (evenly spaced), one critic trained
#: on each half of them and scored on the other (the paired fit's critic at its end, with one seed); none with fewer
#: than :data:`MIN_CRITIC_IMAGES` images of at least a critic's patch a side (half of them train it).
CRITIC_IMAGES = 16
MIN_CRITIC_IMAGES = 4
CRITIC_SEEDS = 1


def common_crops(cleans: Sequence[Tensor], captures: Sequence[Tensor]) -> tuple[list[Tensor], list[Tensor]]:
    """Each clean image with a capture (in turn), both cropped to their common size, where that is at least a
    critic's patch a side: a critic's patches are cut at the same places of the capture and of the clean image's
    simulation (the scenes differ: unpaired)."""
    kept_cleans, kept_captures = [], []
    for index, clean in enumerate(cleans):
        capture = captures[index % len(captures)]
        height = min(clean.shape[-2], capture.shape[-2])
        width = min(clean.shape[-1], capture.shape[-1])
        if min(height, width) >= PATCH:
            kept_cleans.append(clean[:, :height, :width])
            kept_captures.append(capture[:, :height, :width])
    return kept_cleans, kept_captures


def self_check_critic(
    simulate: Callable[[list[Tensor]], list[Tensor]], cleans: Sequence[Tensor], captures: Sequence[Tensor]
) -> dict[str, Any] | None:
    """A fresh image-only critic's accuracy at telling ``simulate(cleans)`` (stored as the captures are) from the
    ``captures``, scored on images it did not train on (:func:`~camdegrade.measures.critic.repeated_critic_test`,
    :data:`CRITIC_SEEDS` seed); ``None`` where fewer than :data:`MIN_CRITIC_IMAGES` images can be used."""
    cleans, captures = common_crops(evenly_spaced(cleans, CRITIC_IMAGES), evenly_spaced(captures, CRITIC_IMAGES))
    if len(cleans) < MIN_CRITIC_IMAGES:
        return None
    scenes = [f"{index:04d}" for index in range(len(cleans))]
    return repeated_critic_test((cleans, captures, simulate(cleans)), scenes, CRITIC_SEEDS, image_only=True).to_dict()


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
    edges = fidelity.get("band_edges", [])  # a band content alone moves past the gate is a note (unmeasured_bands)
    off = [
        f"{edges[index]:g}–{edges[index + 1]:g} cycles/pixel {value:+.2f}"
        for index, (value, spread) in enumerate(_with_spread(fidelity))
        if abs(value) > BAND_GATE_LOG2 and SIGNIFICANCE * spread <= BAND_GATE_LOG2 and index + 1 < len(edges)
    ]
    if with_clean and any(name in wanted for name in DETAIL_STAGES) and off:
        out.append(
            f"the fit's own check: band power of the simulated clean set against the captures beyond "
            f"±{BAND_GATE_LOG2:g} log2 ({', '.join(off)}); the captures' detail is not reproduced"
        )
    critic = fidelity.get("critic_image_only")
    if critic and critic["accuracy"] > CRITIC_WARNING_ACCURACY:
        out.append(
            f"the fit's own check: a fresh image-only critic tells the simulated clean set from the captures at "
            f"{critic['accuracy']:.2f} [{critic['low']:.2f}–{critic['high']:.2f}] on images it did not train on "
            f"(0.5: cannot tell; above {CRITIC_WARNING_ACCURACY:g}: a model trained on the simulation can tell it "
            "from the camera, unless the two sets' scenes differ in kind, which the critic reads too)"
        )
    return out


def band_spread(real_bands: Tensor, sim_bands: Tensor, seed: int) -> list[float]:
    """Each band's split-half standard error (log2) of the check's band reading, the set means' difference of the
    per-image log2 band powers ``sim_bands`` ``(M, B)`` and ``real_bands`` ``(N, B)``
    (:func:`split_half_error`): what the two sets' content alone moves it by at their size."""

    def estimate(real_indices: list[int], sim_indices: list[int]) -> Tensor:
        return sim_bands[sim_indices].mean(0) - real_bands[real_indices].mean(0)

    error = split_half_error(estimate, len(real_bands), len(sim_bands), seed)
    return [round(float(value), 3) for value in error]


def unmeasured_bands(fidelity: Mapping[str, Any], wanted: Sequence[str], *, with_clean: bool) -> list[str]:
    """What the fit's own check could not measure (none where it measured everything), each with its numbers: the
    bands whose reading content alone moves past the gate, :data:`SIGNIFICANCE` split-half standard errors
    (:func:`band_spread`) wider than :data:`BAND_GATE_LOG2`. Such a band is neither warned of
    (:func:`self_check_warnings`) nor passed silently: ten 128² PolyU crops beside 24 clean crops spread 0.77–1.54
    log2 (docs/results.md, "The PolyU unpaired case against its truth")."""
    edges = fidelity.get("band_edges", [])
    hidden = [
        f"{edges[index]:g}–{edges[index + 1]:g} cycles/pixel {value:+.2f} ± {spread:.2f}"
        for index, (value, spread) in enumerate(_with_spread(fidelity))
        if SIGNIFICANCE * spread > BAND_GATE_LOG2 and index + 1 < len(edges)
    ]
    if not (with_clean and any(name in wanted for name in DETAIL_STAGES) and hidden):
        return []
    return [
        f"the fit's own check: band power not measurable with these sets ({', '.join(hidden)} log2: the reading ± "
        f"its split-half standard error; {SIGNIFICANCE:g} of them exceed the ±{BAND_GATE_LOG2:g} log2 gate, so the "
        "sets' content alone could make or hide a misfit there); more or larger images would measure it"
    ]


def _with_spread(fidelity: Mapping[str, Any]) -> list[tuple[float, float]]:
    """``(band reading, its split-half spread)`` per band; a record without spreads (written before they were
    measured) reads as measured exactly."""
    bands = fidelity.get("bands", [])
    return list(zip(bands, fidelity.get("band_spread") or [0.0] * len(bands), strict=True))
