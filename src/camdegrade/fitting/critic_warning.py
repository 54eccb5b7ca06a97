"""The warning a paired fit gives when its own validation critic tells the simulation from the captures: what a model
trained on the simulation would see, the statistics that differ most, and the command that looks for the cause.

A fit's paired PSNR can be excellent while the sampled profile is plain to see as a simulation (a camera built
outside the effect vocabulary: a default fit at 45.7 dB held-out whose image-only critic read 0.975), and the fit
printed the critic's number without a word on what it means. The critic is the image-only one (what a trained model
sees); the paired critic also reads the captures' misregistration and is reported, never warned about."""

from __future__ import annotations

import math
import shlex
from collections.abc import Mapping
from typing import Any

from camdegrade._support.text import not_an_option

__all__ = ["CRITIC_WARNING_ACCURACY", "critic_tells", "critic_warning", "diagnose_command", "differing_statistics"]

#: Image-only critic accuracy above which a fit warns: the bar a fit's held-out critic is held to (issue 42). 0.5 is a
#: critic that cannot tell; the City100 built-in reads 0.64 (eight single critics 0.55–0.83, docs/results.md). The
#: fit's own critic, on its few validation scenes, estimates the held-out one to a few hundredths (the foreign
#: cameras: 0.72 on validation against 0.75 held out, 0.65 against 0.74), so a warning above 0.75 left fits whose
#: held-out critic was over the bar silent.
CRITIC_WARNING_ACCURACY = 0.70
#: A statistic is named when it is off by at least this much (log2: 0.25 is 19 % of the power or the noise).
NAMED_LOG2 = 0.25
#: At most this many statistics are named, the largest first.
NAMED_MOST = 3
PROFILE_PLACEHOLDER = "PROFILE"
PAIRS_PLACEHOLDER = "PAIRS"


def critic_warning(fidelity: Mapping[str, Any] | None, pairs: str | None) -> list[str]:
    """The warning (a list of at most one) for a fit whose validation image-only critic is above
    :data:`CRITIC_WARNING_ACCURACY`; ``fidelity``: :func:`~camdegrade.fitting.quality.validation_quality`'s record,
    ``pairs``: the path the pairs were given as (``None``: tensors, named ``PAIRS``)."""
    if not critic_tells(fidelity):
        return []
    critic = (fidelity or {})["critic_image_only"]
    named = differing_statistics(fidelity or {})
    found = (
        "the statistics that differ most: " + ", ".join(text for _, text in named)
        if named
        else "no statistic the fit measures (bands, flat noise, grid, banding) differs by "
        f"{NAMED_LOG2:g} log2 or more: the difference is in texture they do not measure (aliasing, demosaicing, "
        "codec patterns, the noise's fine structure)"
    )
    return [
        f"the validation image-only critic tells the sampled profile from the captures at {critic['accuracy']:.2f} "
        f"[{critic.get('low', math.nan):.2f}–{critic.get('high', math.nan):.2f}] (0.5: cannot tell; above "
        f"{CRITIC_WARNING_ACCURACY:g}: a model trained on the simulation can tell it from the camera); {found}; "
        f"look for the cause with `{diagnose_command(None, pairs)}`, best on pairs the fit did not see"
    ]


def critic_tells(fidelity: Mapping[str, Any] | None) -> bool:
    """Whether the validation image-only critic of ``fidelity`` is above :data:`CRITIC_WARNING_ACCURACY`."""
    critic = (fidelity or {}).get("critic_image_only")
    return isinstance(critic, Mapping) and critic.get("accuracy", 0.0) > CRITIC_WARNING_ACCURACY


def differing_statistics(fidelity: Mapping[str, Any]) -> list[tuple[float, str]]:
    """The fidelity statistics (:mod:`camdegrade.measures.fidelity`) off by :data:`NAMED_LOG2` log2 or more, the
    largest first (at most :data:`NAMED_MOST`): (how far in log2, the statistic in words)."""
    found = []
    for key, label in (("noise_ratio", "flat noise"), ("grid_ratio", "8×8 grid"), ("banding_ratio", "banding")):
        ratio = fidelity.get(key)
        if isinstance(ratio, (int, float)) and ratio > 0:
            found.append((abs(math.log2(ratio)), f"{label} {ratio:.2f}× the captures'"))
    edges = fidelity.get("band_edges") or []
    for index, value in enumerate(fidelity.get("bands") or []):
        if isinstance(value, (int, float)) and index + 1 < len(edges):
            band = f"{edges[index]:g}–{edges[index + 1]:g} cycles/px"
            found.append((abs(value), f"band power {band} {value:+.2f} log2"))
    found = [item for item in found if item[0] >= NAMED_LOG2]
    return sorted(found, key=lambda item: -item[0])[:NAMED_MOST]


def diagnose_command(profile: str | None, pairs: str | None) -> str:
    """``camdegrade diagnose PROFILE PAIRS`` with each path quoted for a POSIX shell (a placeholder where unknown;
    a path starting with ``-`` is prefixed ``./`` so that it is not read as an option)."""
    names = [profile or PROFILE_PLACEHOLDER, pairs or PAIRS_PLACEHOLDER]
    return shlex.join(["camdegrade", "diagnose", *(not_an_option(name) for name in names)])
