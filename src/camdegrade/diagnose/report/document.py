"""The diagnosis report: JSON (a fixed schema) and one self-contained HTML page (no external requests).

Plots are PNG images drawn with matplotlib when it is installed (the optional ``report`` extra) and embedded as
base64; without matplotlib the same evidence is shown as tables. Example crops are always embedded (Pillow).
"""

from __future__ import annotations

import html
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from torch import Tensor

from camdegrade._support.files import atomic_path
from camdegrade.diagnose.report._html import table
from camdegrade.diagnose.report.critic_html import critic_section
from camdegrade.diagnose.report.crops import crop_grid
from camdegrade.diagnose.report.plots import evidence_plots, fallback_tables
from camdegrade.measures import FAMILIES
from camdegrade.measures.critic.explain import SurePatch
from camdegrade.profile import CameraProfile

__all__ = ["REQUIRED_KEYS", "DiagnosisReport", "render_html"]

#: Keys every JSON report has at the top level (more follow them).
REQUIRED_KEYS = ("gap_before", "gap_after", "noise_floor", "where", "effects", "added")


@dataclass
class DiagnosisReport:
    """What :func:`camdegrade.diagnose.diagnose` found. ``to_dict()`` is the JSON report."""

    gap_before: float
    gap_after: float
    noise_floor: float
    where: list[dict[str, Any]]
    effects: list[dict[str, Any]]
    added: list[str]
    verdict: str = ""
    fraction_closed: float = 0.0
    gap_before_se: float = 0.0
    gap_after_best_single: float = 0.0
    combinations: list[dict[str, Any]] = field(default_factory=list)
    fitted_params: dict[str, dict[str, Any]] = field(default_factory=dict)
    split: str = ""
    calibration_pairs: int = 0
    held_out_pairs: int = 0
    families_before: dict[str, float] = field(default_factory=dict)
    families_after: dict[str, float] = field(default_factory=dict)
    statistics: dict[str, dict[str, Tensor]] = field(default_factory=dict, repr=False)
    crops: list[tuple[str, list[Tensor]]] = field(default_factory=list, repr=False)
    profile: CameraProfile | None = field(default=None, repr=False)
    profile_name: str = ""
    mode: str = "paired"
    changes: list[dict[str, Any]] = field(default_factory=list)
    accepted: list[str] = field(default_factory=list)
    critic: dict[str, dict[str, Any]] = field(default_factory=dict)
    skipped: list[dict[str, str]] = field(default_factory=list)
    fit_statistics: dict[str, Any] = field(default_factory=dict)
    flat_crops: list[tuple[str, list[Tensor]]] = field(default_factory=list, repr=False)
    #: The held-out patches each critic was surest about (``label`` → ``SurePatch`` list), for the HTML page.
    critic_surest: dict[str, list[SurePatch]] = field(default_factory=dict, repr=False)
    #: What a person sees, simulation beside capture: the network's 4-pixel grid and the texture (band power).
    visible: list[dict[str, Any]] = field(default_factory=list)
    #: The accepted changes to what the profile has (its own misfit), each a change row.
    misfit: list[dict[str, Any]] = field(default_factory=list)
    #: Every candidate effect the profile lacks, ranked by held-out gap once its misfit is fixed; ``accepted`` marks
    #: the ones the diagnosis added.
    missing: list[dict[str, Any]] = field(default_factory=list)
    #: The accepted changes judged in order by an image-only critic: ``steps`` let through (the profile as given
    #: first) and the one ``held_back`` (:mod:`camdegrade.diagnose.critic_check`); empty without the critic.
    critic_check: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """The JSON report: the required keys first, then the evidence."""
        return {
            "gap_before": _number(self.gap_before),
            "gap_after": _number(self.gap_after),
            "noise_floor": _number(self.noise_floor),
            "where": self.where,
            "effects": self.effects,
            "added": list(self.added),
            "verdict": self.verdict,
            "visible": self.visible,
            "misfit": self.misfit,
            "missing": self.missing,
            "mode": self.mode,
            "fraction_closed": _number(self.fraction_closed),
            "gap_before_se": _number(self.gap_before_se),
            "gap_after_best_single": _number(self.gap_after_best_single),
            "combinations": self.combinations,
            "fitted_params": self.fitted_params,
            "split": self.split,
            "calibration_pairs": self.calibration_pairs,
            "held_out_pairs": self.held_out_pairs,
            "families_before": {k: _number(v) for k, v in self.families_before.items()},
            "families_after": {k: _number(v) for k, v in self.families_after.items()},
            "gap_definition": (
                "sum over statistic families of RMS((real - sim) / sqrt(tau^2 + SE^2)), noise levels as log std; "
                "see docs/diagnosis.md"
            ),
            "family_tau": {name: family.tau for name, family in FAMILIES.items()},
            "profile": self.profile_name,
            "changes": self.changes,
            "accepted": list(self.accepted),
            "critic": self.critic,
            "critic_check": self.critic_check,
            "skipped": self.skipped,
            "fit_statistics": self.fit_statistics,
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, allow_nan=False) + "\n"

    def write_json(self, path: str | os.PathLike[str]) -> Path:
        path = Path(path)
        with atomic_path(path) as temporary:
            temporary.write_text(self.to_json(), encoding="utf-8")
        return path

    def write_html(self, path: str | os.PathLike[str]) -> Path:
        path = Path(path)
        with atomic_path(path) as temporary:
            temporary.write_text(self.to_html(), encoding="utf-8")
        return path

    def to_html(self) -> str:
        return render_html(self)


def _number(value: float) -> float:
    return round(float(value), 4) if math.isfinite(float(value)) else 0.0


def _pm(value: float, error: float | None, needed: float | None = None) -> str:
    """A reduction with its standard error, or what it needed to count where it was not bootstrapped."""
    if error is not None:
        return f"{value:+.2f} ± {error:.2f}"
    return f"{value:+.2f}" if needed is None else f"{value:+.2f} (below the {needed:.2f} that counts)"


_STYLE = (
    "body{font-family:sans-serif;max-width:1000px;margin:2em auto;color:#222}"
    "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #ccc;padding:3px 8px;font-size:13px}"
    ".verdict{font-size:1.3em;padding:0.8em;background:#eef5ff;border-left:6px solid #3870c0}"
    ".crops img{margin:2px;image-rendering:pixelated}.muted{color:#777;font-size:0.9em}"
)


def render_html(report: DiagnosisReport) -> str:
    """One self-contained page: verdict, numbers, where, ranking, evidence plots and example crops."""
    title = f"camdegrade diagnosis: {html.escape(report.profile_name or 'profile')}"
    return (
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{title}</title><style>{_STYLE}</style></head>"
        f"<body><h1>{title}</h1><p class='verdict'>{html.escape(report.verdict)}</p>{_numbers(report)}"
        f"<p class='muted'>{html.escape(report.split)}. Candidates are fitted on the calibration pairs; every gap "
        "is measured on the held-out pairs. Gap = Σ over statistic families of RMS((real − sim)/τ).</p>"
        f"{critic_section(report.critic, report.critic_surest)}{_critic_check(report.critic_check)}"
        f"<h2>Where the gap lies (before)</h2>{_where(report)}{_visible(report)}"
        f"<h2>Which change: candidates ranked</h2>{_findings(report)}{_changes(report)}{_combinations(report)}"
        f"<h2>Evidence</h2>{_evidence(report)}{_flat_crops(report)}{_crops(report)}"
        "</body></html>\n"
    )


def _critic_check(check: dict[str, Any]) -> str:
    """The accepted changes as the image-only critic judged them, in order (nothing without the check)."""
    if not check:
        return ""
    given, *judged = check["steps"]
    rows = [(given["change"], _interval(given), "")]
    rows += [(step["change"], _interval(step), "let through") for step in judged]
    held = check["held_back"]
    if held is not None:
        rows.append((held["change"], _interval(held), f"held back: {held.get('texture_after', '')}"))
        rows.extend((label, "not judged", "held back with it") for label in check["later_held_back"])
    header = ("change (in the order accepted)", "image-only critic after it", "")
    return "<h3>The accepted changes, checked by the image-only critic and the texture</h3>" + table(rows, header)


def _interval(score: dict[str, Any]) -> str:
    return f"{score['accuracy']:.2f} [{score['low']:.2f}–{score['high']:.2f}]"


def _numbers(report: DiagnosisReport) -> str:
    return table(
        [
            ("gap before (profile as is)", f"{report.gap_before:.2f} ± {report.gap_before_se:.2f}"),
            ("gap after (added: " + (", ".join(report.added) or "nothing") + ")", f"{report.gap_after:.2f}"),
            ("noise floor (final profile against itself)", f"{report.noise_floor:.2f}"),
            ("fraction of the gap above the floor closed", f"{report.fraction_closed:.0%}"),
        ],
        ("quantity", "value"),
    )


def _where(report: DiagnosisReport) -> str:
    rows = [
        (
            w["axis"],
            f"{w['score']:.2f}",
            f"{w.get('null', 0.0):.2f}",
            "yes" if w.get("significant") else "no",
            w["finding"],
        )
        for w in report.where
    ]
    return table(rows, ("axis", "score", "null", "significant", "finding"))


def _visible(report: DiagnosisReport) -> str:
    if not report.visible:
        return ""
    rows = [
        (entry["look"], "yes" if entry["significant"] else "no", entry["finding"], entry.get("after_finding", ""))
        for entry in report.visible
    ]
    return "<h3>What a person sees (simulation beside capture)</h3>" + table(
        rows, ("look", "significant", "profile as given", "with the accepted changes")
    )


def _changes(report: DiagnosisReport) -> str:
    rows = [
        (
            f"{c['kind']} {c['name']}",
            f"{c['gap_after']:.2f}",
            _pm(c["reduction"], c.get("reduction_se"), c.get("reduction_needed")),
            "yes" if c.get("significant") else "no",
            c.get("error") or c.get("description", ""),
        )
        for c in report.changes
    ]
    return table(rows, ("change", "held-out gap", "reduction", "significant", "what it says"))


def _findings(report: DiagnosisReport) -> str:
    """The two findings: the profile's own misfit (the accepted fixes) and the effects it lacks, ranked once the
    misfit is fixed."""
    misfit = [(f"{c['kind']} {c['name']}", f"{c['reduction']:+.2f}", c.get("description", "")) for c in report.misfit]
    missing = [
        (
            f"{c['kind']} {c['name']}",
            f"{c['gap_after']:.2f}",
            _pm(c["reduction"], c.get("reduction_se"), c.get("reduction_needed")),
            "yes" if c.get("accepted") else "no",
        )
        for c in report.missing
    ]
    on_top = " (once the misfit is fixed)" if report.misfit else ""
    return (
        "<h3>The profile's own misfit (what it has, refitted)</h3>"
        + (table(misfit, ("change", "reduction", "what it says")) if misfit else "<p>none found</p>")
        + f"<h3>Effects the camera has and the profile lacks, ranked{on_top}</h3>"
        + table(missing, ("effect", "held-out gap", "reduction", "accepted"))
    )


def _combinations(report: DiagnosisReport) -> str:
    if not report.combinations:
        return ""
    rows = [
        (" + ".join([*c["after"], f"{c['kind']} {c['name']}"]), f"{c['gap_after']:.2f}", f"{c['reduction']:+.2f}")
        for c in report.combinations
    ]
    return "<h3>Combinations (fitted on top of the accepted changes)</h3>" + table(
        rows, ("changes", "held-out gap", "marginal reduction")
    )


def _flat_crops(report: DiagnosisReport) -> str:
    return crop_grid("A flat region at 1:1 (real | sim before | sim after)", report.flat_crops, scale=1)


def _evidence(report: DiagnosisReport) -> str:
    figures = "".join(
        f"<figure><img src='{url}' alt='{html.escape(caption)}'><figcaption>{html.escape(caption)}</figcaption>"
        "</figure>"
        for caption, url in evidence_plots(report.statistics)
    )
    return figures or fallback_tables(report.statistics)


def _crops(report: DiagnosisReport) -> str:
    return crop_grid("Examples (clean | real | sim before | sim after)", report.crops)
