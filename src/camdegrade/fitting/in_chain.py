"""A stage fitted where it sits in a profile's chain (:meth:`Effect.fit_in_chain`): the profile's deterministic
output is the source, and the profile with the stage in place is simulated on demand, so that a stage whose look
depends on the stages after it (noise, through the tone curve and the codec) is calibrated through them."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from torch import Tensor

from camdegrade._support.pixels import as_unit
from camdegrade.effects import STAGES, Effect, Noise, Resolution
from camdegrade.network.inference import run_network
from camdegrade.profile import CameraProfile

__all__ = [
    "CALIBRATION_PAIRS",
    "after_resampler",
    "fit_noise_stage",
    "fit_stage_in_chain",
    "in_its_place",
    "noise_places",
    "replace_stage",
]

#: A stage that calibrates itself by simulation uses about this many pairs (every ⌊N / this⌋-th of N pairs, so
#: between this many and twice as many): about 1 Mpixel at 256².
CALIBRATION_PAIRS = 32


def fit_stage_in_chain(
    profile: CameraProfile,
    kind: type[Effect],
    cleans: Sequence[Tensor],
    captures: Sequence[Tensor],
    *,
    seed: int = 0,
    calibration_pairs: int | None = None,
    sources: Sequence[Tensor] | None = None,
    insert: Callable[[CameraProfile, Effect], CameraProfile] | None = None,
) -> Effect:
    """A stage of ``kind`` for ``profile`` (its stages of that kind that draw only noise are replaced), fitted by
    ``kind.fit_in_chain`` on ``(profile's deterministic output, capture)`` pairs. ``sources``: that output, when
    the caller already has it (it draws nothing, so any seed gives the same images). ``insert``: how the stage is
    put into the profile (default :func:`replace_stage`; the diagnosis tries other places in the chain)."""
    insert = replace_stage if insert is None else insert
    if sources is None:
        sources = profile.simulate(cleans, seed, stream="noise-sources", deterministic=True)
    network_outputs: dict[int, Tensor] = {}

    def simulate_with(effect: Effect, indices: Sequence[int]) -> list[Tensor]:
        # The network's output does not change between candidates: computed once per image, the stages run on it.
        for index in indices:
            if index not in network_outputs:
                network_outputs[index] = _network_output(profile, cleans[index])
        stages = CameraProfile(None, insert(profile, effect).effects)
        return stages.simulate([network_outputs[index] for index in indices], seed, stream="noise-calibration")

    return kind.fit_in_chain(
        list(cleans), list(sources), list(captures), simulate_with, seed=seed, calibration_pairs=calibration_pairs
    )


def fit_noise_stage(
    profile: CameraProfile,
    cleans: Sequence[Tensor],
    captures: Sequence[Tensor],
    *,
    seed: int = 0,
    calibration_pairs: int | None = None,
) -> Effect:
    """The noise stage for ``profile`` (any it has is replaced), calibrated through the stages after it on every
    ``⌊N / calibration_pairs⌋``-th of the N pairs (:meth:`Noise.fit_in_chain`; all when ``None``)."""
    return fit_stage_in_chain(profile, Noise, cleans, captures, seed=seed, calibration_pairs=calibration_pairs)


def _network_output(profile: CameraProfile, clean: Tensor) -> Tensor:
    """What ``profile``'s network makes of ``clean`` (float in [0, 1]; the clean image itself without a network)."""
    with torch.no_grad():
        if profile.network is None:
            return as_unit(clean)
        return run_network(profile.network, clean[None])[0]


def replace_stage(profile: CameraProfile, effect: Effect) -> CameraProfile:
    """``profile`` with ``effect`` at its stage, in place of the stages of its kind that draw only noise (a fitted
    noise stage is the whole of the noise, not an addition to it)."""
    return profile.with_chain(_without_noise_like(profile, effect)).with_effects(effect)


def in_its_place(profile: CameraProfile, effect: Effect) -> CameraProfile:
    """``profile`` with ``effect`` where the first of its kind's stages that draw only noise sits now (the others of
    them dropped), or at its own stage (:func:`replace_stage`) where it has none: a refit keeps the place an earlier
    step chose (noise after a resampler stays after it)."""
    chain = list(profile.effects)
    places = [index for index, stage in enumerate(chain) if type(stage) is type(effect) and stage.draws_only_noise()]
    if not places:
        return replace_stage(profile, effect)
    chain[places[0]] = effect
    return profile.with_chain([stage for index, stage in enumerate(chain) if index not in places[1:]])


def _without_noise_like(profile: CameraProfile, effect: Effect) -> list[Effect]:
    """``profile``'s chain less the stages of ``effect``'s kind that draw only noise."""
    return [e for e in profile.effects if not (type(e) is type(effect) and type(e).draws_only_noise())]


def after_resampler(profile: CameraProfile, effect: Effect) -> CameraProfile:
    """``profile`` with ``effect`` right after its ``resolution`` stage (the resampler), in place of the stages of
    its kind that draw only noise, as :func:`replace_stage` does at the stage's own place: noise that a camera adds
    after its resize (an analog link, a second gain) comes out white there, where noise put before the resize comes
    out upsampled and correlated."""
    chain = _without_noise_like(profile, effect)
    places = [index for index, stage in enumerate(chain) if isinstance(stage, Resolution)]
    if not places:
        raise ValueError(f"profile has no resolution stage to put {effect.name} after (its chain: {chain})")
    chain.insert(places[-1] + 1, effect)
    return profile.with_chain(chain)


def noise_places(
    profile: CameraProfile, kind: type[Effect]
) -> dict[str, Callable[[CameraProfile, Effect], CameraProfile]]:
    """Where a stage of ``kind`` that draws only noise can go in ``profile``, by name: at its own stage
    (:func:`replace_stage`; before a resampler of the ISP), and where the chain resamples after that place, right
    after the resampler too (:func:`after_resampler`). A stage of any other kind has its own place alone."""
    places: dict[str, Callable[[CameraProfile, Effect], CameraProfile]] = {"at its stage": replace_stage}
    if not kind.draws_only_noise():
        return places
    own = sum(1 for effect in profile.effects if STAGES.index(effect.stage) <= STAGES.index(kind.stage))
    if any(isinstance(effect, Resolution) for effect in profile.effects[own:]):
        places["after resolution"] = after_resampler
    return places
