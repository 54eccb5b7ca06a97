"""The effect stages after a fit's network: each fitted on the training pairs at its place in the chain, kept only
where the validation pairs show that the camera has it (:mod:`camdegrade.fitting.steps.noise_evidence`), and
recorded with that evidence (``fitted['effects'][name]``). Where the network was dropped, a colour shift between the
channels that the pairs show comes first (:mod:`camdegrade.fitting.colour_shift`): the network held it. A
position-dependent stage is judged with the network's output curve refitted through it (:func:`retoned`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from camdegrade._support.recipes import DEFAULT_EFFECTS
from camdegrade.effects import EFFECTS, JPEG, STAGES, Color, ColorFilterArray, Effect, Resolution, check_effect_names
from camdegrade.fitting.colour_shift import colour_shift
from camdegrade.fitting.evidence import CfaStage
from camdegrade.fitting.in_chain import CALIBRATION_PAIRS, fit_stage_in_chain, noise_places
from camdegrade.fitting.jpeg_evidence import JpegStage
from camdegrade.fitting.network import chain_tone
from camdegrade.fitting.steps.base import FitStep, PairedFit, Verdict
from camdegrade.fitting.steps.noise_evidence import noise_evidence, on_flat_pixels, placed_noise, relative_gain
from camdegrade.network import ShiftNetwork
from camdegrade.profile import CameraProfile

__all__ = ["DEFAULT_EFFECTS", "EffectStage", "EffectStages", "profile_gain", "retoned"]

#: A position-dependent stage is kept where it removes at least this share of the held-out mean squared error.
MIN_RELATIVE_GAIN = 0.01


@dataclass(frozen=True)
class EffectStages(FitStep):
    """The effects step: the stages ``names`` (effects of the registry; ``()``: none), each an
    :class:`EffectStage` in the order light meets them; its record is theirs by name."""

    name: ClassVar[str] = "effects"
    names: tuple[str, ...] = DEFAULT_EFFECTS

    def __post_init__(self) -> None:
        object.__setattr__(self, "names", tuple(check_effect_names(self.names)))
        if Resolution.name in self.names:
            raise ValueError(
                "effects: 'resolution' is not fitted after the network (it would blur twice); the network is trained "
                "through it: use sensor_scale (--sensor-scale): 'auto' finds it in the captures, or a scale such as 0.5"
            )

    def run(self, fit: PairedFit) -> dict[str, Any]:
        # In the order light meets them; but the colour filter array last: its trace is judged through the codec.
        ordered = sorted(
            self.names, key=lambda name: (name == ColorFilterArray.name, STAGES.index(EFFECTS[name].stage))
        )
        records = {}
        if fit.network is not None and not fit.network.kept and Color.name not in self.names:
            records[Color.name] = self._colour_shift(fit)
        return {**records, **{name: self._stage(name).run(fit) for name in ordered}}

    @staticmethod
    def _stage(name: str) -> FitStep:
        """The stage's step; JPEG's and the colour filter array's are judged by their traces
        (:mod:`~camdegrade.fitting.jpeg_evidence`, :mod:`~camdegrade.fitting.evidence.cfa`)."""
        traced = {JPEG.name: JpegStage, ColorFilterArray.name: CfaStage}
        return traced[name]() if name in traced else EffectStage(EFFECTS[name])

    @staticmethod
    def _colour_shift(fit: PairedFit) -> dict[str, Any]:
        """The colour stage of a shift between the channels, kept where the pairs of every scene show one
        (:func:`~camdegrade.fitting.colour_shift.colour_shift`), before the other stages are fitted through it."""
        scenes = [*fit.train.scenes, *fit.val.scenes]
        stage, record = colour_shift(fit.train_pairs, [*fit.train_pairs, *fit.val_pairs], scenes, fit.say)
        if stage is not None:
            fit.keep(True, stage)
        return record


@dataclass(frozen=True)
class EffectStage(FitStep):
    """One effect stage: proposed by its class at its place in the profile's chain, fitted on (the profile's
    deterministic output, capture) of the training pairs (:meth:`Effect.fit_in_chain`: within its fitter's budget;
    noise calibrated through the stages already in the profile); judged on the validation pairs (the training pairs
    when there are none)."""

    kind: type[Effect]

    @property
    def name(self) -> str:  # type: ignore[override]
        return self.kind.name

    def propose(self, fit: PairedFit) -> Effect | dict[str, Effect] | Verdict:
        """The stage fitted on the training pairs at its place; a noise stage of a chain that resamples after the
        sensor at each of its places (:func:`~camdegrade.fitting.in_chain.noise_places`), by place."""
        absent = self._absent_noise(fit)
        if absent is not None:  # dropped whatever it would be fitted to: not fitted (the same record)
            return absent
        cleans = [clean for clean, _ in fit.train_pairs]
        captured = [target for _, target in fit.train_pairs]
        simulated = fit.profile.simulate(cleans, seed=0, deterministic=True)
        places = noise_places(fit.profile, self.kind)
        try:
            fitted = {
                where: fit_stage_in_chain(
                    fit.profile,
                    self.kind,
                    cleans,
                    captured,
                    calibration_pairs=CALIBRATION_PAIRS,
                    sources=simulated,
                    insert=insert,
                )
                for where, insert in places.items()
            }
        except ValueError as error:  # e.g. too few pixels to estimate it
            fit.say(f"effect {self.kind.name}: not fitted ({error})")
            return Verdict({"kept": False, "reason": str(error)})
        return fitted if len(fitted) > 1 else next(iter(fitted.values()))

    def _absent_noise(self, fit: PairedFit) -> Verdict | None:
        """For a stage that draws only noise: the record and log line :meth:`judge` would give when the validation
        pairs show no noise above the profile's, which do not depend on the stage fitted (its evidence without the
        stage decides), so the costly fit by simulation is skipped; ``None`` otherwise (noise measurably present,
        too few flat pixels to tell, or no validation pairs: then the stage is fitted and judged)."""
        if not self.kind.draws_only_noise() or not fit.val_pairs:
            return None
        pairs = zip(*fit.val_pairs, strict=True)
        _, evidence = noise_evidence(fit.profile, None, *pairs, eight_bit=fit.eight_bit)
        if evidence.present or evidence.capture_noise is None or evidence.capture_over_simulation_low is None:
            return None
        fit.say(f"effect {self.kind.name}: {evidence.describe()} [evidence: validation]")
        return Verdict({**evidence.to_dict(), "evidence": "validation"})

    def judge(self, fit: PairedFit, effect: Effect | dict[str, Effect]) -> dict[str, Any]:
        """The stage kept (``effect``, ``effect`` less its banding, or none) and its record. A stage that draws
        only noise is judged by :func:`~camdegrade.fitting.steps.noise_evidence.noise_evidence` on the validation
        pairs (on the training pairs when there are none, or they hold too few flat pixels); a position-dependent
        one is kept where it lowers the validation error by :data:`MIN_RELATIVE_GAIN`; any other is kept. Noise
        fitted at several places is judged at each and kept at one of them
        (:func:`~camdegrade.fitting.steps.noise_evidence.placed_noise`)."""
        if isinstance(effect, dict):
            return placed_noise(fit, effect)
        kept, record, line = self._evidence(fit, effect)
        fit.say(f"effect {self.kind.name}: {line}")
        if isinstance(kept, CameraProfile):  # the stage with the network's tone refitted through it
            fit.profile = kept
        elif kept is not None:
            fit.keep(True, kept)
        return record

    def _evidence(self, fit: PairedFit, effect: Effect) -> tuple[Effect | CameraProfile | None, dict[str, Any], str]:
        if type(effect).draws_only_noise():
            (kept, evidence), label = on_flat_pixels(
                fit,
                lambda pairs: noise_evidence(fit.profile, effect, *zip(*pairs, strict=True), eight_bit=fit.eight_bit),
                lambda judged: judged[1].capture_noise is not None,
            )
            return kept, {**evidence.to_dict(), "evidence": label}, f"{evidence.describe()} [evidence: {label}]"
        pairs, label = fit.evidence_pairs
        if effect.position_dependent:
            return _position_dependent(fit, effect, pairs, label)
        return effect, {"kept": True}, f"fitted ({effect.extra_repr()})"


def _position_dependent(
    fit: PairedFit, effect: Effect, pairs: list, label: str
) -> tuple[Effect | CameraProfile | None, dict[str, Any], str]:
    """A position-dependent stage judged with the network's output curve refitted through it where the network has
    one (:func:`retoned`: its fit drops the exposure it solves for, which the network's tone must then carry),
    against the profile with that curve refitted without it (so that the stage is not credited with what the refit
    alone gains), kept where it lowers the validation error by :data:`MIN_RELATIVE_GAIN`."""
    inputs = _curve_inputs(fit, fit.profile.network)  # one network pass serves both refits: the network is theirs
    candidate, _ = retoned(fit, fit.profile.with_effects(effect), inputs)
    if candidate is None:
        gain = relative_gain(fit.profile, effect, *zip(*pairs, strict=True))
    else:
        reference, _ = retoned(fit, fit.profile, inputs)
        gain = profile_gain(reference, candidate, pairs)
    kept = gain >= MIN_RELATIVE_GAIN
    note = {"kept": kept, "relative_mse_gain": round(gain, 4), "evidence": label, "chain_tone": candidate is not None}
    line = f"relative MSE gain {gain:.2%} on {len(pairs)} {label} pair(s) -> {'kept' if kept else 'dropped'}"
    line += " (the network's output curve refitted through it)" if candidate is not None else ""
    return ((candidate or effect) if kept else None), note, line


def retoned(
    fit: PairedFit, profile: CameraProfile, inputs: chain_tone.CurveInputs | None = None
) -> tuple[CameraProfile | None, str]:
    """``profile`` with its network's output curve refitted through its deterministic stages on whole frames of the
    training pairs (every ⌊N / 32⌋-th, 4 Mpixels at most: :func:`~camdegrade.fitting.network.chain_tone.refit_pairs`),
    or ``None`` and why not: no output curve, or no gradient through a stage. ``inputs``: :func:`_curve_inputs` of
    ``profile``'s network, where the caller has them."""
    network = profile.network
    if not chain_tone.has_output_curve(network):
        return None, "the network has no output curve"
    stages = list(profile.without_randomness().effects)
    if inputs is None:
        inputs = _curve_inputs(fit, network)
    try:
        knots = chain_tone.refit_output_curve(network.curve[1], inputs, stages)
    except ValueError as error:
        return None, str(error)
    network = chain_tone.with_output_curve(network, knots)
    return CameraProfile(network, list(profile.effects), name=profile.name, description=profile.description), ""


def _curve_inputs(fit: PairedFit, network: ShiftNetwork | None) -> chain_tone.CurveInputs | None:
    """What the network's output curve reads on the refit's whole frames (``None`` where it has no curve)."""
    if not chain_tone.has_output_curve(network):
        return None
    return chain_tone.curve_inputs(network, chain_tone.refit_pairs(fit.train_pairs, CALIBRATION_PAIRS))


def profile_gain(before: CameraProfile, after: CameraProfile, pairs: list) -> float:
    """The share of ``before``'s mean squared error against the captures of ``pairs`` that ``after`` removes
    (deterministic outputs; negative where it adds error)."""
    cleans, captures = [clean for clean, _ in pairs], [captured for _, captured in pairs]
    errors = [
        sum(float((sim - captured).pow(2).sum()) for sim, captured in zip(sims, captures, strict=True))
        for sims in (profile.simulate(cleans, 0, deterministic=True) for profile in (before, after))
    ]
    return 1.0 - errors[1] / errors[0] if errors[0] > 0 else 0.0
