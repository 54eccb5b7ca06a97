"""The effect stages after a fit's network: each fitted on the training pairs, kept only where the validation pairs
show that the camera has it (:mod:`camdegrade.fitting.evidence`), and recorded with that evidence."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from camdegrade.effects import EFFECTS, STAGES, Effect
from camdegrade.fitting.evidence import noise_evidence, relative_gain
from camdegrade.fitting.noise import CALIBRATION_PAIRS, fit_stage_in_chain
from camdegrade.fitting.pairset import simulate
from camdegrade.fitting.training import ImagePair
from camdegrade.profile import CameraProfile

#: A position-dependent stage is kept where it removes at least this share of the held-out mean squared error.
MIN_RELATIVE_GAIN = 0.01

Log = Callable[[str], None]


def fit_effects(
    profile: CameraProfile,
    fit_pairs: Sequence[ImagePair],
    held_out: Sequence[ImagePair],
    names: Sequence[str],
    say: Log,
    *,
    eight_bit: bool,
) -> tuple[CameraProfile, dict[str, Any]]:
    """Fit each requested effect on (the profile's deterministic output, capture) of ``fit_pairs`` (the training
    pairs), in the order light meets them, and keep it only where ``held_out`` pairs (the validation pairs; the
    training pairs when there are none) show that the camera has it (:func:`_judge`). Each is fitted by its class at
    its place in the chain (:meth:`Effect.fit_in_chain`: within its fitter's budget; noise calibrated through the
    stages already in the profile)."""
    notes: dict[str, Any] = {}
    cleans = [clean for clean, _ in fit_pairs]
    captured = [target for _, target in fit_pairs]
    for name in sorted(names, key=lambda n: STAGES.index(EFFECTS[n].stage)):
        kind = EFFECTS[name]
        absent = _absent_noise(profile, kind, held_out, eight_bit)
        if absent is not None:  # dropped whatever it would be fitted to: not fitted (the same note)
            notes[name], line = absent
            say(f"effect {name}: {line}")
            continue
        simulated = simulate(profile, cleans, seed=0, deterministic=True)
        try:
            effect = fit_stage_in_chain(
                profile, kind, cleans, captured, calibration_pairs=CALIBRATION_PAIRS, sources=simulated
            )
        except ValueError as error:  # e.g. too few pixels to estimate it
            notes[name] = {"kept": False, "reason": str(error)}
            say(f"effect {name}: not fitted ({error})")
            continue
        kept, notes[name], line = _judge(profile, effect, held_out, fit_pairs, eight_bit)
        say(f"effect {name}: {line}")
        if kept is not None:
            profile = profile.with_effects(kept)
    return profile, notes


def _absent_noise(
    profile: CameraProfile, kind: type[Effect], held_out: Sequence[ImagePair], eight_bit: bool
) -> tuple[dict[str, Any], str] | None:
    """For a stage that draws only noise, judged on the validation pairs: the note and log line :func:`_judge`
    would give when those pairs show no noise above the profile's, which do not depend on the stage fitted (its
    evidence without the stage decides), so the costly fit by simulation is skipped; ``None`` otherwise (noise
    measurably present, too few flat pixels to tell, or no validation pairs: then the stage is fitted and judged)."""
    if not kind.draws_only_noise() or not held_out:
        return None
    _, evidence = noise_evidence(profile, None, *zip(*held_out, strict=True), eight_bit=eight_bit)
    if evidence.present or evidence.capture_noise is None or evidence.capture_over_simulation_low is None:
        return None
    return {**evidence.to_dict(), "evidence": "validation"}, f"{evidence.describe()} [evidence: validation]"


def _judge(
    profile: CameraProfile,
    effect: Effect,
    held_out: Sequence[ImagePair],
    fit_pairs: Sequence[ImagePair],
    eight_bit: bool,
) -> tuple[Effect | None, dict[str, Any], str]:
    """The stage to keep (``effect``, ``effect`` less its banding, or ``None``), its note for ``fitted['effects']``
    and a line for the log. A stage that draws only noise is judged by :func:`~camdegrade.fitting.evidence.
    noise_evidence` on the held-out pairs (on the training pairs when there are none, or they hold too few flat
    pixels); a position-dependent one is kept where it lowers the held-out error by 1 %; any other requested stage
    is kept."""
    pairs, label = (held_out, "validation") if held_out else (fit_pairs, "training")
    if type(effect).draws_only_noise():
        kept, evidence = noise_evidence(profile, effect, *zip(*pairs, strict=True), eight_bit=eight_bit)
        if evidence.capture_noise is None and held_out:
            kept, evidence = noise_evidence(profile, effect, *zip(*fit_pairs, strict=True), eight_bit=eight_bit)
            label = "training (the validation pairs hold too few flat pixels)"
        return kept, {**evidence.to_dict(), "evidence": label}, f"{evidence.describe()} [evidence: {label}]"
    if effect.position_dependent:
        gain = relative_gain(profile, effect, *zip(*pairs, strict=True))
        kept = gain >= MIN_RELATIVE_GAIN
        note = {"kept": kept, "relative_mse_gain": round(gain, 4), "evidence": label}
        line = f"relative MSE gain {gain:.2%} on {len(pairs)} {label} pair(s) -> {'kept' if kept else 'dropped'}"
        return (effect if kept else None), note, line
    return effect, {"kept": True}, f"fitted ({effect.extra_repr()})"
