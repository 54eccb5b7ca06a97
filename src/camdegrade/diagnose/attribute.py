"""Which unmodelled effect causes the sim-to-real gap, and how far adding it closes the gap.

Method (``docs/diagnosis.md``): split the real pairs by scene into a calibration part and a held-out part. For
every effect in :data:`camdegrade.effects.EFFECTS`, fit it on the calibration part on top of the profile
(source: the profile's output without its random stages; target: the real capture), insert it into the chain
at its physical stage, simulate the held-out clean images and measure the held-out gap. Candidates are ranked by
gap reduction; the best is added when its reduction is significant (beyond three bootstrap standard errors and
a minimum size), then the next candidates are refitted on top of it (combinations), until nothing helps.
"""

from __future__ import annotations

import copy
import hashlib
import math
import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from camdegrade.diagnose.noise_fit import NoiseMoments, calibrate_noise
from camdegrade.diagnose.stats import (
    Scale,
    StatisticSet,
    bootstrap_indices,
    family_gaps,
    flat_mask,
    gap,
    gap_spread,
    measurement_scale,
)
from camdegrade.effects import EFFECTS, Effect, Noise
from camdegrade.errors import CamdegradeError
from camdegrade.pairs import Pair, PairReport, discover_pairs, load_pair, split_by_scene
from camdegrade.profile import CameraProfile, load_profile

#: Stochastic stages: left out of the profile output that candidate effects are fitted against.
STOCHASTIC = frozenset({"noise"})
#: At most this many calibration pairs go to the slower, iterative fitters (all pairs go to closed-form ones).
FIT_PAIRS: dict[str, int] = {"misalignment": 12, "distortion": 16, "chromatic_aberration": 16, "blur": 24, "jpeg": 16}
#: A reduction counts when it exceeds this many bootstrap standard errors ...
SIGNIFICANCE = 3.0
#: ... and this absolute size (gap units: one family off by one tau everywhere is 1) ...
MIN_REDUCTION = 0.5
#: ... and this share of the gap above the noise floor.
MIN_RELATIVE = 0.1
BOOTSTRAP_ROUNDS = 100
#: Calibration pairs on which the strength of each fitted candidate is refined.
REFINE_PAIRS = 12
#: Calibration pairs on which the noise candidate's level is calibrated by simulation (noise statistics only):
#: at most ``NOISE_PAIRS``, fewer for large images (about ``NOISE_PIXELS`` pixels), at least ``MIN_NOISE_PAIRS``.
NOISE_PAIRS = 32
NOISE_PIXELS = 1 << 20
MIN_NOISE_PAIRS = 8

ImagePairs = list[tuple[Tensor, Tensor]]
PairsInput = str | os.PathLike[str] | PairReport | Sequence[Pair] | Sequence[tuple[Tensor, Tensor]]


@dataclass
class Candidate:
    """One candidate (an effect, or effects added in sequence) evaluated on the held-out pairs."""

    names: list[str]
    effects: list[Effect]
    profile: CameraProfile | None
    gap_after: float
    reduction: float
    reduction_se: float
    significant: bool = False
    families: dict[str, float] = field(default_factory=dict)
    error: str | None = None
    stats: StatisticSet | None = field(default=None, repr=False)

    def params(self) -> dict[str, Any]:
        return {effect.name: effect_params(effect) for effect in self.effects}


def effect_params(effect: Effect) -> dict[str, Any]:
    """An effect's fitted values (buffers) and options (config), JSON-serialisable."""
    values: dict[str, Any] = {}
    for key, value in effect.state_dict().items():
        values[key] = round(float(value), 6) if value.numel() == 1 else [round(v, 6) for v in value.flatten().tolist()]
    values.update(effect.config())
    return values


def load_image_pairs(
    pairs: PairsInput,
    *,
    clean_suffix: str | None = None,
    captured_suffix: str | None = None,
    max_pairs: int | None = None,
) -> tuple[ImagePairs, list[str]]:
    """Float (clean, captured) pairs and a scene id per pair, from a path, a report, Pairs or tensor pairs."""
    if isinstance(pairs, (str, os.PathLike)):
        pairs = discover_pairs(Path(pairs), clean_suffix=clean_suffix, captured_suffix=captured_suffix)
    if isinstance(pairs, PairReport):
        pairs = pairs.pairs
    items = list(pairs)
    if not items:
        raise ValueError("pairs must hold at least one (clean, captured) pair")
    if max_pairs is not None:
        items = items[:max_pairs]
    if all(isinstance(item, Pair) for item in items):
        loaded = [load_pair(item) for item in items]
        scenes = [item.scene for item in items]
    elif all(isinstance(item, (tuple, list)) and len(item) == 2 for item in items):
        loaded = [(item[0], item[1]) for item in items]
        scenes = [str(index) for index in range(len(items))]
    else:
        raise TypeError("pairs must be a path, a PairReport, a list of Pair or a list of (clean, captured) tensors")
    out = []
    for index, (clean, captured) in enumerate(loaded):
        clean, captured = _unit(clean), _unit(captured)
        if clean.ndim != 3 or clean.shape[0] != 3 or clean.shape != captured.shape:
            raise ValueError(
                f"pair {index}: clean and captured must be (3, H, W) of the same size, "
                f"got {tuple(clean.shape)} and {tuple(captured.shape)}"
            )
        out.append((clean, captured))
    return out, scenes


def _unit(image: Tensor) -> Tensor:
    return image.float() / 255.0 if image.dtype == torch.uint8 else image.float().clamp(0, 1)


def split_pairs(scenes: Sequence[str], calibration: float, seed: int) -> tuple[list[int], list[int]]:
    """Indices of (calibration, held-out) pairs; no scene on both sides, held-out share ``1 − calibration``."""
    if not 0.0 < calibration < 1.0:
        raise ValueError(f"calibration must be in (0, 1), got calibration={calibration!r}")
    unique = sorted(set(scenes))
    if len(unique) < 2:
        raise ValueError(f"diagnosis needs pairs from at least 2 scenes (calibration and held-out), got {len(unique)}")
    fake = [Pair(Path(str(i)), Path(str(i)), str(i), scene) for i, scene in enumerate(scenes)]
    _, held = split_by_scene(fake, 1.0 - calibration, seed=seed)
    held_names = {pair.name for pair in held}
    if not held_names or len(held_names) == len(scenes):
        held_names = {str(i) for i, scene in enumerate(scenes) if scene in unique[1::2]}
    held_out = [i for i in range(len(scenes)) if str(i) in held_names]
    calib = [i for i in range(len(scenes)) if str(i) not in held_names]
    return calib, held_out


def _image_seed(seed: int, index: int) -> int:
    digest = hashlib.sha256(f"diagnose:{seed}:{index}".encode()).digest()
    return int.from_bytes(digest[:8], "little") & ((1 << 63) - 1)


def simulate(
    profile: CameraProfile, cleans: Sequence[Tensor], seed: int, *, deterministic: bool = False
) -> list[Tensor]:
    """The profile applied to each clean image, image ``i`` seeded from ``(seed, i)``; ``deterministic`` drops
    the random stages (the conditional mean that candidate effects are fitted against)."""
    if deterministic:
        profile = without_stochastic(profile)
    out = []
    with torch.no_grad():
        for index, clean in enumerate(cleans):
            batch = clean[None]
            generator = torch.Generator().manual_seed(_image_seed(seed, index))
            out.append(profile(batch, profile.make_params(batch.shape, generator))[0])
    return out


def without_stochastic(profile: CameraProfile) -> CameraProfile:
    kept = [effect for effect in profile.effects if effect.name not in STOCHASTIC]
    if len(kept) == len(profile.effects):
        return profile
    return CameraProfile(profile.network, kept, name=profile.name, description=profile.description)


def add_effect(profile: CameraProfile, effect: Effect) -> CameraProfile:
    """``profile`` with ``effect`` inserted at its stage; a stochastic effect replaces one of the same name."""
    if effect.name in STOCHASTIC and effect.name in profile.effect_names:
        base = CameraProfile(
            profile.network,
            [e for e in profile.effects if e.name != effect.name],
            name=profile.name,
            description=profile.description,
            fitted=profile.fitted,
            quality=profile.quality,
            package_version=profile.package_version,
        )
        return base.with_effects(effect)
    return profile.with_effects(effect)


def _every(items: Sequence[Any], limit: int) -> list[Any]:
    if len(items) <= limit:
        return list(items)
    step = len(items) / limit
    return [items[int(i * step)] for i in range(limit)]


def fit_candidate(name: str, sources: Sequence[Tensor], targets: Sequence[Tensor]) -> Effect:
    """Fit effect ``name`` so that ``targets ≈ effect(sources)`` (on the pairs its fitter affords)."""
    limit = FIT_PAIRS.get(name)
    if limit is not None:
        sources, targets = _every(sources, limit), _every(targets, limit)
    options: dict[str, Any] = {}
    if name == "blur":  # small images: shrink the crops rather than fail
        side = min(min(image.shape[-2:]) for image in sources)
        options = {"max_sigma": 4.0, "crop": max(16, min(64, side - 2 * 17))}
    if name == "noise":  # few or small pairs: accept intensity bins with fewer pixels
        options = {"min_count": 50}
    return EFFECTS[name].fit(list(sources), list(targets), **options)


#: Neutral values that differ from an effect's constructor defaults (a codec's "nothing" is quality 100).
_NEUTRAL = {"jpeg": {"quality": 100.0}}
STRENGTHS = (0.6, 1.0, 1.6)


def scaled(effect: Effect, strength: float) -> Effect:
    """A copy of ``effect`` whose fitted values are moved from neutral by ``strength`` times the fitted change."""
    neutral = type(effect)().state_dict()
    for key, value in _NEUTRAL.get(effect.name, {}).items():
        neutral[key] = torch.tensor(value)
    out = copy.deepcopy(effect)
    state = {
        key: neutral[key] + strength * (value - neutral[key]) if key in neutral else value
        for key, value in effect.state_dict().items()
    }
    if effect.name == "jpeg":
        state["quality"] = state["quality"].round().clamp(1, 100)
    if effect.name == "noise":
        state = {key: value.clamp_min(0) for key, value in state.items()}
    out.load_state_dict(state)
    return out


def refine_strength(
    effect: Effect, gap_of: Callable[[Effect], float], baseline: float, say: Callable[[str], None]
) -> tuple[Effect, float]:
    """Scale the fitted change so that the effect, at its place in the chain, best matches the calibration
    pairs: the fit itself sees the end of the chain, where later stages (tone, codec) have transformed it.
    A candidate that does not lower the calibration gap (``baseline``) at all is left as fitted."""
    tried = {1.0: gap_of(effect)}
    if tried[1.0] > baseline - MIN_REDUCTION and effect.name not in STOCHASTIC:
        return effect, 1.0
    tried.update({strength: gap_of(scaled(effect, strength)) for strength in STRENGTHS if strength != 1.0})
    best = min(tried, key=tried.__getitem__)
    if best != 1.0:  # extend once past the edge of the bracket
        further = best * (best / 1.0)
        tried[further] = gap_of(scaled(effect, further))
    points = sorted(tried, key=tried.__getitem__)[:3]
    x = torch.tensor([math.log(p) for p in points], dtype=torch.float64)
    y = torch.tensor([tried[p] for p in points], dtype=torch.float64)
    design = torch.stack([x * x, x, torch.ones_like(x)], 1)
    try:
        a, b, _ = torch.linalg.solve(design, y).tolist()
    except RuntimeError:
        a = 0.0
    if a > 0:
        vertex = math.exp(min(max(-b / (2 * a), math.log(0.1)), math.log(10.0)))
        if all(abs(vertex - p) > 0.03 * p for p in tried):
            tried[vertex] = gap_of(scaled(effect, vertex))
    best = min(tried, key=tried.__getitem__)
    say(f"    {effect.name}: strength {best:.2f} (calibration gap {tried[best]:.2f}, at 1: {tried[1.0]:.2f})")
    return scaled(effect, best), best


@dataclass
class HeldOut:
    """The held-out pairs, their real statistics and the bootstrap resamples every gap is judged on."""

    cleans: list[Tensor]
    reals: list[Tensor]
    masks: list[Tensor]
    real: StatisticSet
    indices: Tensor
    seed: int
    scale: Scale | None = None

    @classmethod
    def build(cls, pairs: ImagePairs, seed: int) -> HeldOut:
        cleans = [clean for clean, _ in pairs]
        reals = [real for _, real in pairs]
        masks = [flat_mask(clean) for clean in cleans]
        real = StatisticSet.measure(reals, cleans, masks)
        return cls(cleans, reals, masks, real, bootstrap_indices(len(cleans), BOOTSTRAP_ROUNDS, seed), seed)

    def calibrate(self, profile: CameraProfile) -> tuple[StatisticSet, list[Tensor]]:
        """Fix the yardstick (:func:`measurement_scale`) against ``profile``; return its statistics and
        simulations."""
        stats, sims = self.statistics(profile)
        self.scale = measurement_scale(self.real, stats, self.indices)
        return stats, sims

    def gap(self, stats: StatisticSet) -> float:
        return gap(self.real, stats, scale=self.scale)

    def gap_between(self, first: StatisticSet, second: StatisticSet) -> float:
        return gap(first, second, scale=self.scale)

    def statistics(self, profile: CameraProfile, seed_offset: int = 0) -> tuple[StatisticSet, list[Tensor]]:
        sims = simulate(profile, self.cleans, self.seed + seed_offset)
        return StatisticSet.measure(sims, self.cleans, self.masks), sims


@dataclass
class _NoiseCalibration:
    """Calibration pairs (every ``NOISE_PAIRS``-th) on which a noise candidate is calibrated by simulation."""

    index: list[int]
    cleans: list[Tensor]
    masks: list[Tensor]
    real: NoiseMoments
    seed: int

    @classmethod
    def build(cls, pairs: ImagePairs, seed: int) -> _NoiseCalibration:
        pixels = sum(clean.shape[-1] * clean.shape[-2] for clean, _ in pairs) / len(pairs)
        count = min(NOISE_PAIRS, max(MIN_NOISE_PAIRS, round(NOISE_PIXELS / pixels)))
        index = _every(list(range(len(pairs))), count)
        cleans = [pairs[i][0] for i in index]
        masks = [flat_mask(clean) for clean in cleans]
        real = NoiseMoments.measure([pairs[i][1] for i in index], cleans, masks)
        return cls(index, cleans, masks, real, seed)

    def measure(self, images: list[Tensor]) -> NoiseMoments:
        return NoiseMoments.measure(images, self.cleans, self.masks)

    def calibrate(
        self, effect: Noise, current: CameraProfile, sources: Sequence[Tensor], say: Callable[[str], None]
    ) -> Noise:
        """``effect`` rescaled so that ``current`` with it reproduces the real noise-level function."""
        return calibrate_noise(
            effect,
            lambda e: add_effect(current, e),
            lambda p: simulate(p, self.cleans, self.seed),
            self.real,
            self.measure([sources[i] for i in self.index]),
            self.measure,
            say=say,
        )


@dataclass
class Attribution:
    """Everything the ranking found, for the report."""

    gap_before: float
    gap_before_se: float
    base_families: dict[str, float]
    base_null: float
    base_null_families: dict[str, float]
    singles: list[Candidate]
    combinations: list[Candidate]
    chosen: Candidate | None
    final_profile: CameraProfile
    final_families: dict[str, float]
    noise_floor: float
    base_stats: StatisticSet
    final_stats: StatisticSet
    base_sims: list[Tensor]
    final_sims: list[Tensor]
    significant_gap: bool
    held_real: StatisticSet


def _evaluate(
    held: HeldOut,
    base: StatisticSet,
    before: float,
    threshold: float,
    names: list[str],
    effects: list[Effect],
    profile: CameraProfile,
) -> Candidate:
    stats, _ = held.statistics(profile)
    after = held.gap(stats)
    reduction = before - after
    se, significant = float("nan"), False
    if reduction > threshold:  # otherwise it cannot be significant: skip the bootstrap
        spreads = gap_spread(held.real, [base, stats], held.indices, held.scale)
        se = float((spreads[:, 0] - spreads[:, 1]).std())
        significant = reduction > max(SIGNIFICANCE * se, threshold)
    families = family_gaps(held.real, stats, scale=held.scale)
    return Candidate(names, effects, profile, after, reduction, se, significant, families, stats=stats)


def attribute(
    profile: CameraProfile,
    calibration: ImagePairs,
    held_out: ImagePairs,
    *,
    candidates: Iterable[str] | None = None,
    max_added: int = 3,
    seed: int = 0,
    log: Callable[[str], None] | None = None,
) -> Attribution:
    """Rank candidate effects by held-out gap reduction and choose the ones to add (see the module docstring)."""
    say = log or (lambda message: None)
    names = list(EFFECTS) if candidates is None else list(candidates)
    unknown = [name for name in names if name not in EFFECTS]
    if unknown:
        raise ValueError(f"candidates must be effect names from {sorted(EFFECTS)}, got unknown {unknown}")
    held = HeldOut.build(held_out, seed)
    base_stats, base_sims = held.calibrate(profile)
    null_stats, _ = held.statistics(profile, seed_offset=1)
    before = held.gap(base_stats)
    base_null_families = family_gaps(null_stats, base_stats, scale=held.scale)
    base_null = sum(base_null_families.values())
    spreads = gap_spread(held.real, [base_stats], held.indices, held.scale)
    before_se = float(spreads[:, 0].std())
    excess = max(0.0, before - base_null)
    threshold = max(MIN_REDUCTION, MIN_RELATIVE * excess)
    significant_gap = excess > max(SIGNIFICANCE * before_se, MIN_REDUCTION)
    say(f"held-out gap {before:.2f} ± {before_se:.2f} (profile against itself: {base_null:.2f})")

    cal_cleans = [clean for clean, _ in calibration]
    cal_reals = [real for _, real in calibration]
    check = HeldOut.build(_every(calibration, REFINE_PAIRS), seed + 3)
    check_base, _ = check.calibrate(profile)
    moments = _NoiseCalibration.build(calibration, seed + 5)

    def evaluate_on(
        current: CameraProfile, current_stats: StatisticSet, current_gap: float, chain: list[Candidate], pool: list[str]
    ) -> list[Candidate]:
        sources = simulate(current, cal_cleans, seed + 2, deterministic=True)
        check_gap = check.gap(check_base if current is profile else check.statistics(current)[0])
        results = []
        for name in pool:
            previous = chain[-1] if chain else None
            prefix_names = previous.names if previous else []
            prefix_effects = previous.effects if previous else []
            try:
                effect = fit_candidate(name, sources, cal_reals)
                if isinstance(effect, Noise):
                    effect = moments.calibrate(effect, current, sources, say)
                else:
                    effect, _ = refine_strength(
                        effect,
                        lambda e: check.gap(check.statistics(add_effect(current, e))[0]),
                        check_gap,
                        say,
                    )
            except (ValueError, RuntimeError, CamdegradeError) as error:
                say(f"  {name}: not fitted ({error})")
                results.append(
                    Candidate([*prefix_names, name], [*prefix_effects], None, current_gap, 0.0, 0.0, error=str(error))
                )
                continue
            candidate = _evaluate(
                held,
                current_stats,
                current_gap,
                threshold,
                [*prefix_names, name],
                [*prefix_effects, effect],
                add_effect(current, effect),
            )
            say(
                f"  {'+'.join(candidate.names)}: gap {candidate.gap_after:.2f} "
                f"(reduction {candidate.reduction:+.2f} ± {candidate.reduction_se:.2f})"
                f"{' *' if candidate.significant else ''}"
            )
            results.append(candidate)
        return sorted(results, key=lambda c: c.gap_after)

    say("single candidates:")
    singles = evaluate_on(profile, base_stats, before, [], names)
    chain: list[Candidate] = []
    combinations: list[Candidate] = []
    current, current_stats, current_gap = profile, base_stats, before
    pool = [c.names[-1] for c in singles if c.significant]
    if significant_gap and singles and singles[0].significant:
        best = singles[0]
        while True:
            chain.append(best)
            current = best.profile  # type: ignore[assignment]
            current_stats = best.stats if best.stats is not None else held.statistics(current)[0]
            current_gap = best.gap_after
            pool = [name for name in pool if name not in best.names]
            if len(chain) >= max_added or not pool:
                break
            say(f"on top of {'+'.join(best.names)}:")
            extended = evaluate_on(current, current_stats, current_gap, chain, pool)
            combinations.extend(extended)
            if not extended or not extended[0].significant:
                break
            best = extended[0]
    chosen = chain[-1] if chain else None
    final_profile = chosen.profile if chosen and chosen.profile is not None else profile
    if chosen is not None and chosen.stats is not None:  # measured on the same seed when it was evaluated
        final_stats, final_sims = chosen.stats, simulate(final_profile, held.cleans, held.seed)
    else:
        final_stats, final_sims = base_stats, base_sims
    final_null, _ = held.statistics(final_profile, seed_offset=1)
    noise_floor = held.gap_between(final_null, final_stats)
    return Attribution(
        gap_before=before,
        gap_before_se=before_se,
        base_families=family_gaps(held.real, base_stats, scale=held.scale),
        base_null=base_null,
        base_null_families=base_null_families,
        singles=singles,
        combinations=combinations,
        chosen=chosen,
        final_profile=final_profile,
        final_families=family_gaps(held.real, final_stats, scale=held.scale),
        noise_floor=noise_floor,
        base_stats=base_stats,
        final_stats=final_stats,
        base_sims=base_sims,
        final_sims=final_sims,
        significant_gap=significant_gap,
        held_real=held.real,
    )


def resolve_profile(profile: CameraProfile | str | os.PathLike[str]) -> CameraProfile:
    return profile if isinstance(profile, CameraProfile) else load_profile(profile)
