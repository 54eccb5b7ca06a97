"""``diagnose(profile, pairs)``: where the sim-to-real gap lies, which change to the profile closes it, how far it
shrinks, and whether a learned critic agrees."""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable

from camdegrade._support.checks import check_seed
from camdegrade.diagnose.attribution.attribute import Attribution, attribute, check_candidates, keeping
from camdegrade.diagnose.attribution.changes import KINDS, Change, check_kinds, effect_params
from camdegrade.diagnose.critic_check import CriticCheck, check_changes
from camdegrade.diagnose.critique import Critique, critiques
from camdegrade.diagnose.report import DiagnosisReport
from camdegrade.diagnose.report.crops import example_crops, flat_crops
from camdegrade.diagnose.verdict import IMAGE_ONLY, command_reference, fraction_closed, refit_command, verdict_text
from camdegrade.diagnose.where import findings, visible
from camdegrade.errors import PairsError
from camdegrade.measures import check_explains
from camdegrade.measures.visible import GridComparison, compare_grid
from camdegrade.pairs.pairset import PairSet, PairsSource
from camdegrade.profile import CameraProfile, as_profile

__all__ = ["MIN_PAIRS", "diagnose", "findings_of"]

#: Fewest pairs on each side of the split: below this a held-out gap has no spread to judge it by, and the
#: diagnosis refuses rather than state a verdict from one or two pairs.
MIN_PAIRS = 4


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
    command = refit_command(command_reference(profile, "PROFILE"), command_reference(pairs, "PAIRS"))
    verdict = verdict_text(result, where, seen, critics, command, check)
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
        fraction_closed=fraction_closed(result),
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
    ranking = _errors_last(result.missing_ranking)
    return [
        {**row, "accepted": _was_accepted(change, ranking, result.missing)}
        for row, change in zip(_change_rows(ranking), ranking)
    ]


def _was_accepted(change: Change, ranking: list[Change], accepted: list[Change]) -> bool:
    """Whether ``change`` of the missing ranking was accepted: that very change, or its effect where the ranking holds
    it at one place only (accepted on top of another change, it is another object). An effect tried at two places
    (noise before and after a resampler) is accepted at one of them, not at both."""
    if any(change is chosen for chosen in accepted):
        return True
    places = sum(other.key == change.key for other in ranking)
    return places == 1 and any(chosen.key == change.key for chosen in accepted)


def _finite(value: float) -> float | None:
    """Rounded, or ``None`` where it was not computed (JSON has no NaN)."""
    return round(value, 4) if math.isfinite(value) else None
