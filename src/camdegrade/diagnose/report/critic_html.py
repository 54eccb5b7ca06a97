"""The critic's part of the diagnosis page: its accuracy before and after the changes with its interval, its accuracy
by texture, intensity, colour and position, and the held-out patches it is surest about, real beside simulated at
2× nearest-neighbour (:func:`~camdegrade.measures.critic.explain.render_surest`): what a person needs to believe or
doubt its verdict."""

from __future__ import annotations

import html
from collections.abc import Mapping, Sequence
from typing import Any

from camdegrade.diagnose.report._html import png_url, table
from camdegrade.measures.critic.explain import SurePatch, surest_png

__all__ = ["DETAIL_GAIN", "critic_section"]

#: How much the fine detail the critic saw is amplified in the picture (0.5 + gain · detail; grey is none).
DETAIL_GAIN = 4.0


def critic_section(critic: Mapping[str, Mapping[str, Any]], surest: Mapping[str, Sequence[SurePatch]]) -> str:
    """The HTML section (nothing when the critic was not run)."""
    if not critic:
        return ""
    rows = [
        (
            label,
            f"{result['accuracy']:.2f} [{result['low']:.2f}–{result['high']:.2f}]",
            result["patches"],
            " and ".join(
                f"{fold['accuracy']:.2f} ({len(fold['trained_on'])} / {len(fold['scored_on'])})"
                for fold in result.get("folds", [])
            ),
        )
        for label, result in critic.items()
    ]
    summary = table(
        rows,
        ("profile", "held-out accuracy [95 % CI]", "patches", "each fold: accuracy (pairs trained on / scored on)"),
    )
    return (
        "<h2>Learned critic (0.5: cannot tell real from simulated)</h2>"
        f"{summary}<h3>Where it decides: accuracy (patches) by tercile of the clean patch</h3>{_groups(critic)}"
        f"{_pictures(critic, surest)}"
    )


def _groups(critic: Mapping[str, Mapping[str, Any]]) -> str:
    rows = []
    for label, result in critic.items():
        for grouping, tiers in result.get("by_group", {}).items():
            cells = [f"{name} {_accuracy(tier['accuracy'])} ({tier['patches']})" for name, tier in tiers.items()]
            rows.append((label, grouping, *cells))
    return table(rows, ("profile", "grouping", "low tercile", "mid tercile", "high tercile"))


def _accuracy(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.2f}"


def _pictures(critic: Mapping[str, Mapping[str, Any]], surest: Mapping[str, Sequence[SurePatch]]) -> str:
    """One picture per distinct critic (after is before when nothing was accepted)."""
    shown: list[Sequence[SurePatch]] = []
    figures = []
    for label, patches in surest.items():
        if not patches or any(patches is earlier for earlier in shown):
            continue
        shown.append(patches)
        names = critic[label].get("scored_on") or None
        caption = (
            f"Profile {label}: the held-out patches the critic is surest about, real beside simulated at 2× "
            f"nearest-neighbour, then the fine detail it saw (×{DETAIL_GAIN:g}, grey is none)"
        )
        url = png_url(surest_png(patches, scale=2, names=names, detail_gain=DETAIL_GAIN))
        figures.append(
            f"<figure class='crops'><img src='{url}' alt='{html.escape(caption)}'>"
            f"<figcaption>{html.escape(caption)}</figcaption></figure>"
        )
    return "".join(figures)
