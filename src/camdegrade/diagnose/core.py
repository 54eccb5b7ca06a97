"""``diagnose(profile, pairs)``: where the sim-to-real gap lies, which effect causes it, how far it shrinks."""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable

from camdegrade.diagnose.attribute import (
    PairsInput,
    attribute,
    effect_params,
    load_image_pairs,
    resolve_profile,
    split_pairs,
)
from camdegrade.diagnose.report import DiagnosisReport, example_crops
from camdegrade.diagnose.where import findings
from camdegrade.profile import CameraProfile


def diagnose(
    profile: CameraProfile | str | os.PathLike[str],
    pairs: PairsInput,
    *,
    held_out: PairsInput | None = None,
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
            takes), a :class:`~camdegrade.pairs.PairReport`, a list of ``Pair`` or of ``(clean, captured)``
            tensors. They are split by scene into a calibration part (candidate effects are fitted on it) and a
            held-out part (every reported gap is measured on it).
        held_out: give the held-out pairs explicitly; then ``pairs`` is the calibration part as a whole.
        calibration_fraction: share of scenes used for calibration when ``held_out`` is not given.
        candidates: effect names to try (default: every registered effect).
        max_added: the most effects added in sequence (the best combination).
        seed: seeds the split, the simulations and the bootstrap.
        max_pairs: use at most this many pairs (the first, in name order).
        log: called with progress lines.

    Returns:
        A :class:`DiagnosisReport`; ``report.profile`` is the profile with the chosen effects added.
    """
    base = resolve_profile(profile)
    items, scenes = load_image_pairs(
        pairs, clean_suffix=clean_suffix, captured_suffix=captured_suffix, max_pairs=max_pairs
    )
    if held_out is None:
        calibration_index, held_index = split_pairs(scenes, calibration_fraction, seed)
        calibration = [items[i] for i in calibration_index]
        held = [items[i] for i in held_index]
        split = f"split by scene (seed {seed}): {len(calibration)} calibration, {len(held)} held-out pairs"
    else:
        calibration = items
        held, _ = load_image_pairs(held_out, clean_suffix=clean_suffix, captured_suffix=captured_suffix)
        split = f"given: {len(calibration)} calibration, {len(held)} held-out pairs"
    say = log or (lambda message: None)
    say(split)
    result = attribute(base, calibration, held, candidates=candidates, max_added=max_added, seed=seed, log=log)
    chosen = result.chosen
    best_single = next((c for c in result.singles if c.profile is not None), None)
    gap_after = chosen.gap_after if chosen else result.gap_before
    ranked = [c for c in result.singles if c.error is None] + [c for c in result.singles if c.error is not None]
    effects = [
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
    combinations = [
        {
            "names": c.names,
            "gap_after": round(c.gap_after, 4),
            "reduction": round(c.reduction, 4),
            "reduction_se": _finite(c.reduction_se),
            "significant": c.significant,
        }
        for c in result.combinations
    ]
    added = list(chosen.names) if chosen else []
    fitted = {effect.name: effect_params(effect) for effect in chosen.effects} if chosen else {}
    final = result.final_profile
    if added:
        final.fitted = {**final.fitted, "diagnosis": {"added": added, "gap_before": result.gap_before}}
    excess = result.gap_before - result.noise_floor
    fraction = (result.gap_before - gap_after) / excess if excess > 0 else 0.0
    where = findings(result.held_real, result.base_stats, result.base_families, result.base_null_families)
    if not result.significant_gap:
        verdict = (
            f"No significant gap: the held-out gap {result.gap_before:.2f} is within the noise of the measurement "
            f"(profile against itself {result.base_null:.2f}, bootstrap SE {result.gap_before_se:.2f})."
        )
    elif not added:
        verdict = (
            f"Unexplained gap: {result.gap_before:.2f} (noise floor {result.noise_floor:.2f}), mostly in "
            f"{where[0]['axis']}; no candidate effect closes a significant part of it."
        )
    else:
        verdict = (
            f"The profile is missing {' + '.join(added)}: adding it closes {fraction:.0%} of the held-out gap "
            f"({result.gap_before:.2f} → {gap_after:.2f}; noise floor {result.noise_floor:.2f})."
        )
    say(verdict)
    return DiagnosisReport(
        gap_before=result.gap_before,
        gap_after=gap_after,
        noise_floor=result.noise_floor,
        where=where,
        effects=effects,
        added=added,
        verdict=verdict,
        fraction_closed=fraction,
        gap_before_se=result.gap_before_se,
        gap_after_best_single=best_single.gap_after if best_single else result.gap_before,
        combinations=combinations,
        fitted_params=fitted,
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
            [clean for clean, _ in held], [real for _, real in held], result.base_sims, result.final_sims
        ),
        profile=final,
        profile_name=base.name,
    )


def _finite(value: float) -> float | None:
    """Rounded, or ``None`` where it was not computed (JSON has no NaN)."""
    return round(value, 4) if math.isfinite(value) else None
