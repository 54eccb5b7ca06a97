"""The verdict of a diagnosis in words: what it found and what to do (the change to make, or the command that
refits the network), what the critic check held back or uncovered, what a person sees, and whether the critics
agree; and the refit command itself, built with shell quoting from the names the user gave."""

from __future__ import annotations

import os
import shlex

from camdegrade._support.text import not_an_option
from camdegrade.diagnose.attribution.attribute import Attribution
from camdegrade.diagnose.attribution.changes import Change
from camdegrade.diagnose.attribution.signature import not_a_cause_clause
from camdegrade.diagnose.critic_check import CriticCheck, uncovered_clause
from camdegrade.diagnose.critique import CRITIC_CHANCE, Critique
from camdegrade.pairs.pair import PairReport

__all__ = [
    "IMAGE_ONLY",
    "REFIT_OPTIONS",
    "command_reference",
    "critic_clause",
    "finding",
    "finding_sentence",
    "fraction_closed",
    "held_back_clause",
    "refit_command",
    "seen_clause",
    "verdict_text",
]

#: The suffix of the critics' labels that see the image alone, without its clean source.
IMAGE_ONLY = " (image only)"
#: What the suggested network refit adds after ``camdegrade fit PAIRS --init-from PROFILE``.
REFIT_OPTIONS = ("-o", "REFIT.safetensors", "--epochs", "20", "--lr", "0.001")


def fraction_closed(result: Attribution) -> float:
    excess = result.baseline.gap - result.noise_floor
    return (result.baseline.gap - result.gap_after) / excess if excess > 0 else 0.0


def refit_command(profile: str, pairs: str) -> str:
    """The shell command that refits ``profile``'s network on ``pairs``, every argument quoted for a POSIX shell
    (:func:`shlex.join`): a name or path holding ``;``, ``$( )``, quotes or line breaks stays one argument when the
    command is pasted, and one starting with ``-`` is not read as an option."""
    arguments = ["camdegrade", "fit", not_an_option(pairs), *REFIT_OPTIONS[:2]]
    arguments += ["--init-from", not_an_option(profile), *REFIT_OPTIONS[2:]]
    return shlex.join(arguments)


def command_reference(given: object, placeholder: str) -> str:
    """How a suggested command names what the user passed: the path or name as given (a pair report: the folder or
    manifest it was found in), else ``placeholder`` (a profile object or tensors have no name on the command line)."""
    if isinstance(given, PairReport):
        given = given.source
    return os.fspath(given) if isinstance(given, (str, os.PathLike)) else placeholder


def finding(change: Change, refit: str) -> tuple[str, str]:
    """(what is wrong, what fixes it) for an accepted change, in words."""
    if change.kind == "add":
        return f"the profile is missing {change.name}", f"adding {change.name}"
    if change.kind == "remove":  # "noise stage is 4.0× the camera's noise", "vignetting stage is one the camera lacks"
        return f"the profile's {change.description}", f"removing the {change.name} stage"
    if change.kind == "refit":
        return f"the profile's {change.description}", f"refitting {change.name}"
    return "the network itself leaves a gap no effect explains", f"refitting the network ({refit})"


def finding_sentence(misfit: bool, changes: list[Change], refit: str) -> str:
    """One finding in words, the profile's own misfit or the effects it lacks: what is wrong and what fixes it, each
    fix with the gap it took off where it was accepted."""
    parts = [finding(change, refit) for change in changes]
    fixes = ", then ".join(f"{fix} (gap −{change.reduction:.2f})" for (_, fix), change in zip(parts, changes))
    if misfit:
        return f"The profile does not reproduce the camera: {'; '.join(p for p, _ in parts)}; fix: {fixes}."
    lacks = "an effect the profile lacks" if len(changes) == 1 else "effects the profile lacks"
    return f"The camera has {lacks}: {', '.join(change.name for change in changes)}; fix: {fixes}."


def verdict_text(
    result: Attribution,
    where: list[dict],
    seen: list[dict],
    critics: dict[str, Critique],
    refit: str,
    check: CriticCheck | None = None,
) -> str:
    held_back = held_back_clause(check, refit)
    baseline = result.baseline
    if held_back and not result.accepted:
        text = (
            f"No change is accepted: the held-out gap is {baseline.gap:.2f} (noise floor {result.noise_floor:.2f})."
            + held_back
        )
    elif not baseline.significant:
        text = (
            f"No significant gap: the held-out gap {baseline.gap:.2f} is within the noise of the measurement "
            f"(profile against itself {baseline.null:.2f}, bootstrap SE {baseline.gap_se:.2f})."
        )
    elif not result.accepted and result.identity is not None and result.identity.significant:
        text = (
            f"The profile degrades more than the camera: the held-out captures are closer to their clean images "
            f"(gap {result.identity.gap_after:.2f}) than to the profile's simulations ({baseline.gap:.2f}; noise "
            f"floor {result.noise_floor:.2f}), and no single change closes it: remove stages, or refit the profile "
            "on these pairs (camdegrade fit PAIRS -o REFIT.safetensors)."
        )
    elif not result.accepted:
        text = (
            f"Unexplained gap: {baseline.gap:.2f} (noise floor {result.noise_floor:.2f}), mostly in "
            f"{where[0]['axis']}; no change to the profile closes a significant part of it."
        ) + not_a_cause_clause(result.singles)
    else:
        text = " ".join(
            finding_sentence(misfit, changes, refit)
            for misfit, changes in ((True, result.misfit), (False, result.missing))
            if changes
        )
        text += (
            f" {'This closes' if len(result.accepted) == 1 else 'Together they close'} "
            f"{fraction_closed(result):.0%} of the held-out gap ({baseline.gap:.2f} → {result.gap_after:.2f}; "
            f"noise floor {result.noise_floor:.2f})."
        ) + held_back
    return text + uncovered_clause(check) + seen_clause(seen) + critic_clause(baseline.significant, critics)


def held_back_clause(check: CriticCheck | None, refit: str) -> str:
    """The change the image-only critic held back, in words, or nothing."""
    if check is None or check.held_back is None:
        return ""
    change, critique = check.held_back
    before, after = check.steps[-1][1].result, critique.result
    _, fix = finding(change, refit)
    texture = check.texture[1].describe() if check.texture else ""
    clause = (
        f" Held back: {fix} closes the statistics' gap (−{change.reduction:.2f}), but from the image alone a critic "
        f"tells the simulation from the camera more easily with it ({before.accuracy:.2f} [{before.low:.2f}–"
        f"{before.high:.2f}] → {after.accuracy:.2f} [{after.low:.2f}–{after.high:.2f}]), and the texture moves away "
        f"from the camera's: {texture}."
    )
    if check.later:
        labels = ", ".join(later.label for later in check.later)
        clause += f" Held back with it, as accepted on top of it: {labels}."
    return clause


def seen_clause(seen: list[dict]) -> str:
    """What a person sees in the simulation beside the captures (the grid, the texture) when it is significant, and
    what is still seen with the accepted changes (a change the statistics accept can leave it, or deepen it)."""
    parts = [entry["finding"] for entry in seen if entry["significant"]]
    clause = f" What a person sees: {'; '.join(parts)}." if parts else ""
    after = [
        entry["after_finding"]
        for entry in seen
        if "after_finding" in entry and entry["after"] != entry["before"] and _significant_after(entry)
    ]
    return clause + (f" With the changes: {'; '.join(after)}." if after else "")


def _significant_after(entry: dict) -> bool:
    significant = entry["after"]["significant"]
    return any(significant) if isinstance(significant, list) else bool(significant)


def critic_clause(significant_gap: bool, critics: dict[str, Critique]) -> str:
    """What the critic adds to the verdict: its accuracy before and after, and where it disagrees."""
    if not critics:
        return ""
    before, after = critics["before"].result, critics["after"].result
    clause = f" Critic: {before.describe()}"
    if after is not before:
        clause += f"; after the changes {after.accuracy:.2f} [{after.low:.2f}–{after.high:.2f}]"
    clause += "."
    if f"before{IMAGE_ONLY}" in critics:
        seen, seen_after = critics[f"before{IMAGE_ONLY}"].result, critics[f"after{IMAGE_ONLY}"].result
        clause += f" From the image alone: {seen.accuracy:.2f} [{seen.low:.2f}–{seen.high:.2f}]"
        if seen_after is not seen:
            clause += f"; after the changes {seen_after.accuracy:.2f} [{seen_after.low:.2f}–{seen_after.high:.2f}]"
        clause += "."
    if significant_gap and before.low <= 0.5:
        clause += " The critic cannot tell the captures from the simulations although the statistics see a gap."
    elif not significant_gap and before.low > CRITIC_CHANCE:
        clause += (
            " The critic still tells them apart although the statistics see no significant gap: a difference the "
            "statistics do not measure (see where it decides)."
        )
    return clause
