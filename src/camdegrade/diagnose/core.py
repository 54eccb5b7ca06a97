"""``diagnose(profile, pairs)``: where the sim-to-real gap lies, which effect causes it, how far it shrinks."""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from camdegrade._checks import check_seed
from camdegrade.diagnose.attribute import Attribution, Candidate, attribute, effect_params
from camdegrade.diagnose.report import DiagnosisReport, example_crops
from camdegrade.diagnose.where import findings
from camdegrade.errors import PairsError
from camdegrade.fitting.pairset import PairSet, PairsSource
from camdegrade.profile import CameraProfile, as_profile

#: Fewest pairs on each side of the split: below this a held-out gap has no spread to judge it by, and the
#: diagnosis refuses rather than state a verdict from one or two pairs.
MIN_PAIRS = 4


@dataclass
class PairedDiagnosisReport(DiagnosisReport):
    """The report of a paired diagnosis: also lists the files skipped while loading the pairs (``skipped``: one
    ``{"path", "reason"}`` per file), so a dropped pair is never silent."""

    skipped: list[dict[str, str]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {**super().to_dict(), "skipped": self.skipped}


def diagnose(
    profile: CameraProfile | str | os.PathLike[str],
    pairs: PairsSource,
    *,
    held_out: PairsSource | None = None,
    calibration_fraction: float = 0.5,
    candidates: Iterable[str] | None = None,
    max_added: int = 3,
    seed: int = 0,
    clean_suffix: str | None = None,
    captured_suffix: str | None = None,
    max_pairs: int | None = None,
    log: Callable[[str], None] | None = None,
) -> DiagnosisReport:
    """Diagnose the gap between a profile's simulations and REAL captures it was not fitted on.

    Args:
        profile: a :class:`CameraProfile`, a built-in profile name or a ``.safetensors`` path.
        pairs: REAL (clean, captured) pairs: a folder, CSV manifest or suffix-rule folder (as ``camdegrade fit``
            takes), a :class:`~camdegrade.fitting.PairReport`, a list of ``Pair`` or of ``(clean, captured)``
            tensors. They are split by scene into a calibration part (candidate effects are fitted on it) and a
            held-out part (every reported gap is measured on it).
        held_out: give the held-out pairs explicitly; then ``pairs`` is the calibration part as a whole.
        calibration_fraction: share of scenes used for calibration when ``held_out`` is not given.
        candidates: effect names to try (default: every registered effect).
        max_added: the most effects added in sequence (the best combination).
        seed: seeds the split, the simulations and the bootstrap.
        max_pairs: use at most this many pairs (the first, in name order).
        log: called with progress lines (the files skipped while loading the pairs among them).

    Returns:
        A :class:`DiagnosisReport`; ``report.profile`` is the profile with the chosen effects added, and
        ``report.skipped`` lists the files left out while loading the pairs.

    Raises:
        PairsError: fewer than :data:`MIN_PAIRS` calibration or held-out pairs.
    """
    check_seed(seed)
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
    result = attribute(
        base,
        calibration.unit_pairs(),
        held.unit_pairs(),
        candidates=candidates,
        max_added=max_added,
        seed=seed,
        log=log,
    )
    verdict = _verdict(result, findings_of(result))
    say(verdict)
    report = _report(base, result, calibration, held, split, verdict)
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


def findings_of(result: Attribution) -> list[dict]:
    return findings(result.held_real, result.base_stats, result.base_families, result.base_null_families)


def _fraction_closed(result: Attribution) -> float:
    gap_after = result.chosen.gap_after if result.chosen else result.gap_before
    excess = result.gap_before - result.noise_floor
    return (result.gap_before - gap_after) / excess if excess > 0 else 0.0


def _verdict(result: Attribution, where: list[dict]) -> str:
    added = list(result.chosen.names) if result.chosen else []
    if not result.significant_gap:
        return (
            f"No significant gap: the held-out gap {result.gap_before:.2f} is within the noise of the measurement "
            f"(profile against itself {result.base_null:.2f}, bootstrap SE {result.gap_before_se:.2f})."
        )
    if not added:
        return (
            f"Unexplained gap: {result.gap_before:.2f} (noise floor {result.noise_floor:.2f}), mostly in "
            f"{where[0]['axis']}; no candidate effect closes a significant part of it."
        )
    gap_after = result.chosen.gap_after if result.chosen else result.gap_before
    return (
        f"The profile is missing {' + '.join(added)}: adding it closes {_fraction_closed(result):.0%} of the held-out "
        f"gap ({result.gap_before:.2f} → {gap_after:.2f}; noise floor {result.noise_floor:.2f})."
    )


def _effect_rows(singles: list[Candidate]) -> list[dict]:
    ranked = [c for c in singles if c.error is None] + [c for c in singles if c.error is not None]
    return [
        {
            "name": c.names[-1],
            "gap_after": round(c.gap_after, 4),
            "reduction": round(c.reduction, 4),
            "reduction_se": _finite(c.reduction_se),
            "significant": c.significant,
            "params": effect_params(c.effects[-1]) if c.effects and c.error is None else {},
            **({"error": c.error} if c.error else {}),
        }
        for c in ranked
    ]


def _combination_rows(combinations: list[Candidate]) -> list[dict]:
    return [
        {
            "names": c.names,
            "gap_after": round(c.gap_after, 4),
            "reduction": round(c.reduction, 4),
            "reduction_se": _finite(c.reduction_se),
            "significant": c.significant,
        }
        for c in combinations
    ]


def _report(
    base: CameraProfile, result: Attribution, calibration: PairSet, held: PairSet, split: str, verdict: str
) -> PairedDiagnosisReport:
    chosen = result.chosen
    added = list(chosen.names) if chosen else []
    final = result.final_profile
    if added:
        final.fitted = {**final.fitted, "diagnosis": {"added": added, "gap_before": result.gap_before}}
    best_single = next((c for c in result.singles if c.profile is not None), None)
    held_pairs = held.unit_pairs()
    return PairedDiagnosisReport(
        gap_before=result.gap_before,
        gap_after=chosen.gap_after if chosen else result.gap_before,
        noise_floor=result.noise_floor,
        where=findings_of(result),
        effects=_effect_rows(result.singles),
        added=added,
        verdict=verdict,
        fraction_closed=_fraction_closed(result),
        gap_before_se=result.gap_before_se,
        gap_after_best_single=best_single.gap_after if best_single else result.gap_before,
        combinations=_combination_rows(result.combinations),
        fitted_params={effect.name: effect_params(effect) for effect in chosen.effects} if chosen else {},
        split=split,
        calibration_pairs=len(calibration),
        held_out_pairs=len(held),
        families_before=result.base_families,
        families_after=result.final_families,
        statistics={
            "real": result.held_real.values(),
            "before": result.base_stats.values(),
            "after": result.final_stats.values(),
        },
        crops=example_crops(
            [clean for clean, _ in held_pairs], [real for _, real in held_pairs], result.base_sims, result.final_sims
        ),
        profile=final,
        profile_name=base.name,
    )


def _finite(value: float) -> float | None:
    """Rounded, or ``None`` where it was not computed (JSON has no NaN)."""
    return round(value, 4) if math.isfinite(value) else None
