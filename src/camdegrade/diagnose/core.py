"""``diagnose(profile, pairs)``: where the sim-to-real gap lies, which change to the profile closes it, how far it
shrinks, and whether a learned critic agrees."""

from __future__ import annotations

import math
import os
import shlex
from collections.abc import Callable, Iterable

from camdegrade._support.checks import check_seed
from camdegrade._support.text import not_an_option
from camdegrade.diagnose.attribute import Attribution, attribute, check_candidates, keeping
from camdegrade.diagnose.changes import KINDS, Change, check_kinds, effect_params
from camdegrade.diagnose.critic_check import CriticCheck, check_changes, uncovered_clause
from camdegrade.diagnose.critique import CRITIC_CHANCE, Critique, critiques
from camdegrade.diagnose.report import DiagnosisReport, example_crops, flat_crops
from camdegrade.diagnose.signature import not_a_cause_clause
from camdegrade.diagnose.where import findings, visible
from camdegrade.errors import PairsError
from camdegrade.measures import check_explains
from camdegrade.measures.visible import GridComparison, compare_grid
from camdegrade.pairs.pair import PairReport
from camdegrade.pairs.pairset import PairSet, PairsSource
from camdegrade.profile import CameraProfile, as_profile

__all__ = ["IMAGE_ONLY", "MIN_PAIRS", "REFIT_OPTIONS", "diagnose", "findings_of", "refit_command"]

#: Fewest pairs on each side of the split: below this a held-out gap has no spread to judge it by, and the
#: diagnosis refuses rather than state a verdict from one or two pairs.
MIN_PAIRS = 4
#: The suffix of the critics' labels that see the image alone, without its clean source.
IMAGE_ONLY = " (image only)"
#: What the suggested network refit adds after ``camdegrade fit PAIRS --init-from PROFILE``.
REFIT_OPTIONS = ("-o", "REFIT.safetensors", "--epochs", "20", "--lr", "0.001")


def diagnose(
    profile: CameraProfile | str | os.PathLike[str],
    pairs: PairsSource | PairSet,
    *,
    held_out: PairsSource | PairSet | None = None,
    calibration_fraction: float = 0.5,
    candidates: Iterable[str] | None = None,
    kinds: Iterable[str] | None = None,
    max_added: int = 3,
    seed: int = 0,
    clean_suffix: str | None = None,
    captured_suffix: str | None = None,
    max_pairs: int | None = None,
    critic: bool = True,
    log: Callable[[str], None] | None = None,
) -> DiagnosisReport:
    """Diagnose the gap between a profile's simulations and REAL captures it was not fitted on.

    Args:
        profile: a :class:`CameraProfile`, a built-in profile name or a ``.safetensors`` path.
        pairs: REAL (clean, captured) pairs, as :func:`~camdegrade.fitting.fit_profile` takes them: a
            :class:`~camdegrade.pairs.PairSet` (loaded with its options; see :meth:`PairSet.load`), or what it loads:
            a folder, CSV manifest or suffix-rule folder (``clean_suffix``, ``captured_suffix``), a
            :class:`~camdegrade.pairs.PairReport`, a list of ``Pair`` or of ``(clean, captured)`` tensors. They
            are split by scene into a calibration part (changes are fitted on it) and a held-out part (every
            reported gap is measured on it).
        held_out: give the held-out pairs explicitly; then ``pairs`` is the calibration part as a whole.
        calibration_fraction: share of scenes used for calibration when ``held_out`` is not given.
        candidates: effect names that may be added (default: every registered effect).
        kinds: the kinds of change tried: ``"add"`` an effect, ``"remove"`` or ``"refit"`` a stage, ``"network"``
            (a short fine-tune of the network when a signature no effect explains stands out). None: all.
        max_added: the most changes accepted in sequence.
        seed: seeds the split, the simulations, the bootstrap and the critic.
        max_pairs: use at most this many pairs (the first, in name order).
        critic: train the learned critic before and after the accepted changes (``report.critic``); the image-only
            critic also checks each accepted change, and holds back one a model sees more easily that moves the
            texture away from the camera's (``report.critic_check``, :mod:`camdegrade.diagnose.critic_check`).
        log: called with progress lines (the files skipped while loading the pairs among them).

    Returns:
        A :class:`DiagnosisReport`; ``report.profile`` is the profile with every accepted change, and
        ``report.skipped`` lists the files left out while loading the pairs.

    Raises:
        PairsError: fewer than :data:`MIN_PAIRS` calibration or held-out pairs.
    """
    check_seed(seed)
    if isinstance(max_added, bool) or not isinstance(max_added, int) or max_added < 1:
        raise ValueError(f"max_added must be an integer of at least 1, got max_added={max_added!r}")
    kinds = check_kinds(tuple(KINDS) if kinds is None else kinds)
    candidates = check_candidates(candidates)  # before the pairs are loaded
    check_explains()
    say = log or (lambda message: None)
    base = as_profile(profile)
    suffixes = {"clean_suffix": clean_suffix, "captured_suffix": captured_suffix}
    pair_set = PairSet.load(pairs, max_pairs=max_pairs, log=say, **suffixes)
    given = None if held_out is None else PairSet.load(held_out, log=say, **suffixes)
    calibration, held, split = _split(pair_set, given, calibration_fraction, seed)
    if min(len(calibration), len(held)) < MIN_PAIRS:
        raise PairsError(
            f"diagnosis needs at least {MIN_PAIRS} calibration and {MIN_PAIRS} held-out pairs to conclude anything, "
            f"got {len(calibration)} and {len(held)} ({split}); add pairs of more scenes"
        )
    say(split)
    calibration_pairs, held_pairs = calibration.unit_pairs(), held.unit_pairs()
    result = attribute(
        base,
        calibration_pairs,
        held_pairs,
        candidates=candidates,
        kinds=kinds,
        max_changes=max_added,
        seed=seed,
        log=log,
    )
    check = check_changes(result, held, held_pairs, seed, say) if critic and result.accepted else None
    if check is not None and check.held_back is not None:
        result = keeping(result, check.kept, base)
    critics = _critics(result, held, held_pairs, seed, say, check) if critic else {}
    grid = compare_grid(result.baseline.sims, result.held.reals)
    where = findings_of(result, grid)
    seen = visible(result.held.reals, result.baseline.sims, result.final_sims if result.accepted else None, grid=grid)
    command = refit_command(_reference(profile, "PROFILE"), _reference(pairs, "PAIRS"))
    verdict = _verdict(result, where, seen, critics, command, check)
    say(verdict)
    report = _report(base, result, (calibration, held, held_pairs, split), (where, seen, verdict), critics)
    report.critic_check = check.to_dict() if check is not None else {}
    report.skipped = [
        {"path": str(path), "reason": reason}
        for loaded in (pair_set, given)
        if loaded is not None and loaded.report is not None
        for path, reason in loaded.report.skipped
    ]
    return report


def _split(
    pair_set: PairSet, held_out: PairSet | None, calibration_fraction: float, seed: int
) -> tuple[PairSet, PairSet, str]:
    """``(calibration, held-out, description)``: split by scene, or the two sets as given."""
    if held_out is not None:
        return pair_set, held_out, f"given: {len(pair_set)} calibration, {len(held_out)} held-out pairs"
    if not 0.0 < calibration_fraction < 1.0:
        raise ValueError(f"calibration_fraction must be in (0, 1), got calibration_fraction={calibration_fraction!r}")
    if len(set(pair_set.scenes)) < 2:
        raise ValueError(
            f"diagnosis needs pairs from at least 2 scenes (calibration and held-out), got {len(set(pair_set.scenes))}"
        )
    calibration, held = pair_set.split(1.0 - calibration_fraction, seed)
    return (
        calibration,
        held,
        f"split by scene (seed {seed}): {len(calibration)} calibration, {len(held)} held-out pairs",
    )


def findings_of(result: Attribution, grid: GridComparison | None = None) -> list[dict]:
    baseline = result.baseline
    return findings(result.held.real, baseline.stats, baseline.families, baseline.null_families, grid)


def _critics(
    result: Attribution,
    held: PairSet,
    held_pairs: list,
    seed: int,
    say: Callable[[str], None],
    check: CriticCheck | None = None,
) -> dict:
    """The critic on the profile as given and on the profile with the accepted changes (the same one when nothing
    was accepted), each trained and scored on parts of the held-out pairs (:mod:`camdegrade.diagnose.critique`),
    with the clean source beside the image (``before``, ``after``) and from the image alone (``… (image only)``):
    the first also reads a capture's misregistration against its clean image, which no camera effect changes.
    The image-only ones come from ``check`` when it judged the changes (the same simulations and seed)."""
    simulations = [("before", result.baseline.sims)]
    if result.accepted:
        simulations.append(("after", result.final_sims))
    out = critiques(simulations, held_pairs, held.names, held.scenes, seed, say)
    out.setdefault("after", out["before"])
    if check is not None:
        out[f"before{IMAGE_ONLY}"], out[f"after{IMAGE_ONLY}"] = check.steps[0][1], check.steps[-1][1]
        return out
    seen = [(f"{label}{IMAGE_ONLY}", sims) for label, sims in simulations]
    out.update(critiques(seen, held_pairs, held.names, held.scenes, seed, say, image_only=True))
    out.setdefault(f"after{IMAGE_ONLY}", out[f"before{IMAGE_ONLY}"])
    return out


def _fraction_closed(result: Attribution) -> float:
    excess = result.baseline.gap - result.noise_floor
    return (result.baseline.gap - result.gap_after) / excess if excess > 0 else 0.0


def refit_command(profile: str, pairs: str) -> str:
    """The shell command that refits ``profile``'s network on ``pairs``, every argument quoted for a POSIX shell
    (:func:`shlex.join`): a name or path holding ``;``, ``$( )``, quotes or line breaks stays one argument when the
    command is pasted, and one starting with ``-`` is not read as an option."""
    arguments = ["camdegrade", "fit", not_an_option(pairs), *REFIT_OPTIONS[:2]]
    arguments += ["--init-from", not_an_option(profile), *REFIT_OPTIONS[2:]]
    return shlex.join(arguments)


def _reference(given: object, placeholder: str) -> str:
    """How a suggested command names what the user passed: the path or name as given (a pair report: the folder or
    manifest it was found in), else ``placeholder`` (a profile object or tensors have no name on the command line)."""
    if isinstance(given, PairReport):
        given = given.source
    return os.fspath(given) if isinstance(given, (str, os.PathLike)) else placeholder


def _finding(change: Change, refit: str) -> tuple[str, str]:
    """(what is wrong, what fixes it) for an accepted change, in words."""
    if change.kind == "add":
        return f"the profile is missing {change.name}", f"adding {change.name}"
    if change.kind == "remove":  # "noise stage is 4.0× the camera's noise", "vignetting stage is one the camera lacks"
        return f"the profile's {change.description}", f"removing the {change.name} stage"
    if change.kind == "refit":
        return f"the profile's {change.description}", f"refitting {change.name}"
    return "the network itself leaves a gap no effect explains", f"refitting the network ({refit})"


def _finding_sentence(misfit: bool, changes: list[Change], refit: str) -> str:
    """One finding in words, the profile's own misfit or the effects it lacks: what is wrong and what fixes it, each
    fix with the gap it took off where it was accepted."""
    parts = [_finding(change, refit) for change in changes]
    fixes = ", then ".join(f"{fix} (gap −{change.reduction:.2f})" for (_, fix), change in zip(parts, changes))
    if misfit:
        return f"The profile does not reproduce the camera: {'; '.join(p for p, _ in parts)}; fix: {fixes}."
    lacks = "an effect the profile lacks" if len(changes) == 1 else "effects the profile lacks"
    return f"The camera has {lacks}: {', '.join(change.name for change in changes)}; fix: {fixes}."


def _verdict(
    result: Attribution,
    where: list[dict],
    seen: list[dict],
    critics: dict[str, Critique],
    refit: str,
    check: CriticCheck | None = None,
) -> str:
    held_back = _held_back_clause(check, refit)
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
            _finding_sentence(misfit, changes, refit)
            for misfit, changes in ((True, result.misfit), (False, result.missing))
            if changes
        )
        text += (
            f" {'This closes' if len(result.accepted) == 1 else 'Together they close'} "
            f"{_fraction_closed(result):.0%} of the held-out gap ({baseline.gap:.2f} → {result.gap_after:.2f}; "
            f"noise floor {result.noise_floor:.2f})."
        ) + held_back
    return text + uncovered_clause(check) + _seen_clause(seen) + _critic_clause(baseline.significant, critics)


def _held_back_clause(check: CriticCheck | None, refit: str) -> str:
    """The change the image-only critic held back, in words, or nothing."""
    if check is None or check.held_back is None:
        return ""
    change, critique = check.held_back
    before, after = check.steps[-1][1].result, critique.result
    _, fix = _finding(change, refit)
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


def _seen_clause(seen: list[dict]) -> str:
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


def _critic_clause(significant_gap: bool, critics: dict[str, Critique]) -> str:
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


def _errors_last(changes: list[Change]) -> list[Change]:
    return [c for c in changes if c.error is None] + [c for c in changes if c.error is not None]


def _change_rows(changes: list[Change]) -> list[dict]:
    ranked = _errors_last(changes)
    return [
        {
            "kind": c.kind,
            "name": c.name,
            "gap_after": round(c.gap_after, 4),
            "reduction": round(c.reduction, 4),
            "reduction_se": _finite(c.reduction_se),
            "reduction_needed": _finite(c.reduction_needed),
            "significant": c.significant,
            "description": c.description,
            "after": [earlier.label for earlier in c.before],
            "params": effect_params(c.effect) if c.effect is not None else {},
            **({"error": c.error} if c.error else {}),
        }
        for c in ranked
    ]


def _report(
    base: CameraProfile,
    result: Attribution,
    pairs: tuple[PairSet, PairSet, list, str],
    reading: tuple[list[dict], list[dict], str],
    critics: dict[str, Critique],
) -> DiagnosisReport:
    """The report; ``pairs`` = (calibration, held-out, held-out unit pairs, how they were split), ``reading`` =
    (where, what a person sees, verdict)."""
    calibration, held, held_pairs, split = pairs
    where, seen, verdict = reading
    accepted = result.accepted
    added = [change.name for change in accepted if change.kind == "add"]
    final = result.final_profile
    if accepted:
        final.fitted = {
            **final.fitted,
            "diagnosis": {"changes": [change.label for change in accepted], "gap_before": result.baseline.gap},
        }
    adds = [change for change in result.singles if change.kind == "add"]
    best_single = next((c for c in result.singles if c.profile is not None), None)
    cleans, reals = [c for c, _ in held_pairs], [r for _, r in held_pairs]
    changes = _change_rows(result.singles)
    effects = [
        {key: row[key] for key in row if key not in ("kind", "after", "description")} for row in _change_rows(adds)
    ]
    return DiagnosisReport(
        gap_before=result.baseline.gap,
        gap_after=result.gap_after,
        noise_floor=result.noise_floor,
        where=where,
        visible=seen,
        effects=effects,
        added=added,
        verdict=verdict,
        fraction_closed=_fraction_closed(result),
        gap_before_se=result.baseline.gap_se,
        gap_after_best_single=best_single.gap_after if best_single else result.baseline.gap,
        combinations=_change_rows(result.combinations),
        fitted_params={c.name: effect_params(c.effect) for c in accepted if c.effect is not None},
        split=split,
        calibration_pairs=len(calibration),
        held_out_pairs=len(held),
        families_before=result.baseline.families,
        families_after=result.final_families,
        statistics={
            "real": result.held.real.values(),
            "before": result.baseline.stats.values(),
            "after": result.final_stats.values(),
        },
        crops=example_crops(cleans, reals, result.baseline.sims, result.final_sims),
        flat_crops=flat_crops(cleans, reals, result.baseline.sims, result.final_sims),
        profile=final,
        profile_name=base.name,
        changes=changes,
        accepted=[change.label for change in accepted],
        critic={label: value.to_dict() for label, value in critics.items()},
        critic_surest={label: value.explanation.surest for label, value in critics.items()},
        misfit=_change_rows(result.misfit),
        missing=_missing_rows(result),
    )


def _missing_rows(result: Attribution) -> list[dict]:
    """The effects the profile lacks, ranked once its misfit is fixed, each marked whether it was accepted."""
    accepted = {change.key for change in result.missing}
    ranking = _errors_last(result.missing_ranking)
    return [{**row, "accepted": change.key in accepted} for row, change in zip(_change_rows(ranking), ranking)]


def _finite(value: float) -> float | None:
    """Rounded, or ``None`` where it was not computed (JSON has no NaN)."""
    return round(value, 4) if math.isfinite(value) else None
