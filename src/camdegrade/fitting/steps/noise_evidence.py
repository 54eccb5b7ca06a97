"""Whether the camera has an effect, read from pairs its stage was not fitted on (a fit's validation pairs).

A stage fitted after the network always finds *something* to fit: a noise stage fitted to a noiseless camera
reproduces the network's misfit and the captures' 8-bit rounding, and its banding the rows of a few training frames.
So a fit keeps a stage only where held-out pairs show that the camera has the effect and that the profile is closer
to the camera with it:

- **noise** (:func:`noise_evidence`): on pixels where the clean image is flat in absolute terms
  (:func:`~camdegrade.functional.analysis.images.flat_mask`; of the clean images that hold no noise or texture of
  their own there where some do, :func:`~camdegrade.measures.fidelity.quiet_masks`), the capture's noise must be
  measurably above what the profile's deterministic output already has (at least :data:`MIN_NOISE_RATIO` times,
  the bootstrap interval over pairs above 1, and by at least :data:`MIN_EXCESS_LEVELS`), and the sampled profile
  with the stage must have a flat-noise ratio (simulation / capture,
  :func:`~camdegrade.measures.fidelity.noise_ratios`) closer to 1 than without it. Its row and column banding is
  kept only if it brings the row-mean ratio closer to 1 than the same stage without banding
  (:meth:`~camdegrade.effects.Noise.simplified`).
- **where the noise goes** (:func:`placed_noise`): in a chain that resamples after the sensor, a noise stage fitted
  before the resampler and one fitted after it are each judged so; of those kept, the one whose flat-pixel noise is
  nearest the captures' in level and in correlation with the next pixel (a camera's noise added after its resize is
  white; put before the resize it comes out correlated, whatever its level) goes into the profile, at the sensor
  unless the noise there comes out more correlated than the captures' (:data:`CORRELATION_MARGIN`).
- **position-dependent stages** (vignetting, :func:`relative_gain`): the share of the mean squared error they remove.

Simulations are rounded to 8 bits when the captures are 8-bit (:func:`as_stored`: as a training pipeline on uint8
images sees them), so the captures' own rounding is never read as camera noise.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import Any, TypeVar

import torch
from torch import Tensor

from camdegrade._support.pixels import bytes_to_unit, unit_to_bytes
from camdegrade._support.seeds import derived_generator
from camdegrade.effects import Effect
from camdegrade.fitting.in_chain import noise_places, replace_stage
from camdegrade.functional.analysis.images import flat_mask
from camdegrade.functional.analysis.noise import NoiseSums
from camdegrade.measures.fidelity import noise_ratios, quiet_masks
from camdegrade.network.inference import run_network
from camdegrade.pairs.pairset import ImagePair
from camdegrade.profile import CameraProfile

__all__ = [
    "BOOTSTRAP_ROUNDS",
    "CORRELATION_MARGIN",
    "MIN_EXCESS_LEVELS",
    "MIN_NOISE_RATIO",
    "NoiseEvidence",
    "as_stored",
    "noise_evidence",
    "on_flat_pixels",
    "placed_noise",
    "relative_gain",
]

Judged = TypeVar("Judged")

#: The capture's flat noise must be at least this many times the profile's without the stage: below it the
#: profile already has 90 % of the camera's noise (a flat-noise ratio of 0.9 or more) and needs no stage.
MIN_NOISE_RATIO = 1 / 0.9
#: ... and above it by at least this much (8-bit levels, the excess std ``sqrt(capture² − simulation²)``): about
#: the std of 8-bit rounding (1/√12 = 0.29 levels), below which no camera noise can be told from the file format.
MIN_EXCESS_LEVELS = 0.3
BOOTSTRAP_ROUNDS = 1000
#: A noise stage goes after the resampler where, at its own place, its noise comes out more correlated with the next
#: pixel than the captures' by more than this (:func:`placed_noise`; a PIL bicubic 2× upscale of white noise: 0.65
#: against white noise added after it: 0.03, tests/test_noise_placement_fit.py).
CORRELATION_MARGIN = 0.2


def as_stored(images: Sequence[Tensor], eight_bit: bool) -> list[Tensor]:
    """``images`` rounded to 8 bits (``eight_bit``: as the captures are stored), else as they are."""
    return [bytes_to_unit(unit_to_bytes(image)) for image in images] if eight_bit else list(images)


@dataclass
class NoiseEvidence:
    """What held-out pairs say about a fitted noise stage (noise levels in 8-bit levels, ratios simulation over
    capture; ``None`` where not measurable).

    Attributes:
        pairs, flat_pixels: the pairs and the flat pixels of their captures the evidence rests on.
        capture_noise, simulation_noise: flat-pixel noise std of the captures and of the profile's deterministic
            output without the stage.
        capture_over_simulation_low: 2.5 % bootstrap bound (over pairs) of ``capture_noise / simulation_noise``.
        present: the capture's noise is measurably above the simulation's (see the module).
        noise_ratio_without, noise_ratio_with: flat-noise ratio of the profile without the stage and with the stage
            kept (sampled; ``None`` when the stage was not tried).
        correlation_capture, correlation_with: the flat-pixel noise's correlation with the next pixel (mean over
            rows, columns and channels) of the captures and of the profile with the stage kept (``None``: not
            measured); how a stage's place shows (white after a resampler, correlated before it).
        banding_ratio_banded, banding_ratio_unbanded: row-mean ratio with the stage and with it less its banding
            (``None`` both when the stage has no banding).
        banding_kept: the kept stage has banding.
        kept: the stage is kept.
        reason: why, in a few words.
    """

    pairs: int
    flat_pixels: int
    capture_noise: float | None
    simulation_noise: float | None
    capture_over_simulation_low: float | None
    present: bool
    noise_ratio_without: float | None = None
    noise_ratio_with: float | None = None
    correlation_capture: float | None = None
    correlation_with: float | None = None
    banding_ratio_banded: float | None = None
    banding_ratio_unbanded: float | None = None
    banding_kept: bool = False
    kept: bool = False
    reason: str = ""

    def to_dict(self, digits: int = 4) -> dict:
        """Strict JSON: numbers rounded, ``None`` where not measurable."""
        return {key: round(value, digits) if isinstance(value, float) else value for key, value in asdict(self).items()}

    def describe(self) -> str:
        """One line: the numbers the decision rests on, and the decision."""
        text = (
            f"{'kept' if self.kept else 'dropped'} on {self.pairs} pair(s), {self.flat_pixels} flat pixels: capture "
            f"{_number(self.capture_noise)} levels, profile without the stage {_number(self.simulation_noise)}"
        )
        if self.noise_ratio_without is not None:
            text += f"; noise ratio {_number(self.noise_ratio_without)} without it"
        if self.noise_ratio_with is not None:
            text += f", {_number(self.noise_ratio_with)} with it"
        if self.banding_ratio_banded is not None:
            choice = "kept" if self.banding_kept else "dropped"
            text += (
                f"; banding ratio {_number(self.banding_ratio_banded)} with its banding, "
                f"{_number(self.banding_ratio_unbanded)} without -> banding {choice}"
            )
        return f"{text}: {self.reason}"


def _number(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.2f}"


def noise_evidence(
    profile: CameraProfile,
    stage: Effect | None,
    cleans: Sequence[Tensor],
    captures: Sequence[Tensor],
    *,
    eight_bit: bool,
    seed: int = 0,
    insert: Callable[[CameraProfile, Effect], CameraProfile] = replace_stage,
) -> tuple[Effect | None, NoiseEvidence]:
    """The noise stage to keep for ``profile`` (``stage``, ``stage`` without its banding, or ``None``) and the
    evidence on ``(cleans, captures)``: float ``(3, H, W)`` images in [0, 1] the stage was not fitted on. Whether
    the captures hold noise above the profile's is decided without the stage; ``stage=None`` stops there (the
    evidence of a stage not yet fitted: ``present`` says whether fitting one can change anything). ``insert`` puts
    the stage into the profile (default: at its own stage, :func:`~camdegrade.fitting.in_chain.replace_stage`)."""
    masks = quiet_masks(cleans, [flat_mask(clean) for clean in cleans])
    stages, outputs = _network_apart(profile, cleans)
    reals = _sums(captures, cleans, masks)
    bases = _sums(as_stored(stages.simulate(outputs, seed, deterministic=True), eight_bit), cleans, masks)
    real, base = _total(reals), _total(bases)
    capture, simulated = _finite(real.pooled_std()), _finite(base.pooled_std())
    evidence = NoiseEvidence(
        pairs=len(cleans),
        flat_pixels=real.pixels,
        capture_noise=capture,
        simulation_noise=simulated,
        capture_over_simulation_low=_ratio_low(reals, bases, seed),
        present=False,
    )
    if capture is None or simulated is None or evidence.capture_over_simulation_low is None:
        evidence.reason = "too few flat pixels to measure noise"
        return None, evidence
    evidence.noise_ratio_without = noise_ratios(base, real)[0]
    excess = math.sqrt(max(capture**2 - simulated**2, 0.0))
    evidence.present = (
        capture >= MIN_NOISE_RATIO * simulated
        and evidence.capture_over_simulation_low > 1.0
        and excess >= MIN_EXCESS_LEVELS
    )
    if not evidence.present:
        evidence.reason = (
            f"the capture's noise is not measurably above the profile's (that needs {MIN_NOISE_RATIO:.2f}x, a "
            f"bootstrap bound above 1 and {MIN_EXCESS_LEVELS} levels more)"
        )
        return None, evidence
    if stage is None:
        evidence.reason = "noise measurably above the profile's; no stage given to judge"
        return None, evidence

    def sampled(effect: Effect) -> NoiseSums:
        images = insert(stages, effect).simulate(outputs, seed, stream="noise-evidence")
        return _total(_sums(as_stored(images, eight_bit), cleans, masks))

    chosen, with_stage = _banding_choice(stage, real, sampled, evidence)
    evidence.noise_ratio_with = noise_ratios(with_stage, real)[0]
    evidence.correlation_capture, evidence.correlation_with = _next_pixel(real), _next_pixel(with_stage)
    evidence.kept = _closer(evidence.noise_ratio_with, evidence.noise_ratio_without)
    evidence.reason = "closer to the capture's flat noise" if evidence.kept else "no closer to the capture with it"
    return (chosen if evidence.kept else None), evidence


def _network_apart(profile: CameraProfile, cleans: Sequence[Tensor]) -> tuple[CameraProfile, list[Tensor]]:
    """The profile's stages alone, and what its network makes of each clean image: the network runs once per image,
    however many candidate stages are simulated after it (the same images as the whole profile gives)."""
    if profile.network is None:
        return profile, list(cleans)
    with torch.no_grad():
        outputs = [run_network(profile.network, clean[None])[0] for clean in cleans]
    return CameraProfile(None, profile.effects), outputs


def _banding_choice(
    stage: Effect, real: NoiseSums, sampled: Callable[[Effect], NoiseSums], evidence: NoiseEvidence
) -> tuple[Effect, NoiseSums]:
    """The stage with its banding only where that brings the row-mean ratio closer to 1 (recorded in
    ``evidence``), and the sampled sums of the stage chosen."""
    banded = sampled(stage)
    simpler = stage.simplified()
    if not simpler:
        return stage, banded
    unbanded = sampled(simpler[0])
    evidence.banding_ratio_banded = noise_ratios(banded, real)[1]
    evidence.banding_ratio_unbanded = noise_ratios(unbanded, real)[1]
    evidence.banding_kept = _closer(evidence.banding_ratio_banded, evidence.banding_ratio_unbanded)
    return (stage, banded) if evidence.banding_kept else (simpler[0], unbanded)


def _next_pixel(sums: NoiseSums) -> float | None:
    """The flat-pixel noise's correlation with the next pixel, mean over rows, columns and channels."""
    return _finite(float(sums.correlation()[:, 0].mean()))


def _closer(candidate: float | None, reference: float | None) -> bool:
    """Whether the ratio ``candidate`` is closer to 1 than ``reference`` (as factors: 0.5 and 2 are as far);
    ``False`` where ``candidate`` is not measurable."""
    if candidate is None or candidate <= 0:
        return False
    if reference is None or reference <= 0:
        return True
    return abs(math.log(candidate)) < abs(math.log(reference))


def _sums(images: Sequence[Tensor], cleans: Sequence[Tensor], masks: Sequence[Tensor]) -> list[NoiseSums]:
    return [NoiseSums.measure(image, clean, mask) for image, clean, mask in zip(images, cleans, masks, strict=True)]


def _total(sums: Sequence[NoiseSums]) -> NoiseSums:
    total = NoiseSums.zeros()
    for item in sums:
        total = total + item
    return total


def _ratio_low(reals: Sequence[NoiseSums], bases: Sequence[NoiseSums], seed: int) -> float | None:
    """2.5 % quantile of the pooled flat-noise std ratio capture / simulation over pairs drawn with replacement
    (pixels of one frame are not independent: the pair is the unit), of the pairs with flat pixels."""
    real_square = torch.stack([item.square.sum() for item in reals])
    real_count = torch.stack([item.count.sum() for item in reals])
    base_square = torch.stack([item.square.sum() for item in bases])
    base_count = torch.stack([item.count.sum() for item in bases])
    if float(real_count.sum()) == 0 or float(base_count.sum()) == 0:
        return None
    measured = ((real_count > 0) & (base_count > 0)).nonzero().flatten()
    generator = derived_generator(seed, "noise-evidence-bootstrap")
    draws = measured[torch.randint(0, len(measured), (BOOTSTRAP_ROUNDS, len(measured)), generator=generator)]
    real_variance = real_square[draws].sum(1) / real_count[draws].sum(1)
    base_variance = base_square[draws].sum(1) / base_count[draws].sum(1)
    ratio = (real_variance / base_variance).sqrt().nan_to_num(nan=0.0, posinf=1e6)  # a draw of no flat pixel: 0
    return _finite(float(torch.quantile(ratio.clamp_max(1e6), 0.025)))


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def relative_gain(profile: CameraProfile, stage: Effect, cleans: Sequence[Tensor], captures: Sequence[Tensor]) -> float:
    """The share of the mean squared error against the captures that ``stage`` removes from the profile's
    deterministic output (0 where there is none to remove; negative where it adds error)."""
    simulated = profile.simulate(cleans, 0, deterministic=True)
    before = _mean_squared_error(simulated, captures)
    with torch.no_grad():
        after = _mean_squared_error([stage(image[None])[0] for image in simulated], captures)
    return 1 - after / before if before > 0 else 0.0


def _mean_squared_error(predictions: Sequence[Tensor], targets: Sequence[Tensor]) -> float:
    total = sum(float(((p - t) ** 2).sum()) for p, t in zip(predictions, targets, strict=True))
    return total / sum(t.numel() for t in targets)


def on_flat_pixels(
    fit: Any, judge: Callable[[Sequence[ImagePair]], Judged], measured: Callable[[Judged], bool]
) -> tuple[Judged, str]:
    """``judge`` of a :class:`~camdegrade.fitting.steps.PairedFit`'s evidence pairs and their name; of its training
    pairs where the validation pairs hold too few flat pixels for the noise to be ``measured`` there."""
    pairs, label = fit.evidence_pairs
    judged = judge(pairs)
    if not measured(judged) and fit.val_pairs:
        return judge(fit.train_pairs), "training (the validation pairs hold too few flat pixels)"
    return judged, label


def placed_noise(fit: Any, candidates: dict[str, Effect]) -> dict[str, Any]:
    """Judge a noise stage fitted at each place of ``candidates`` (place name → stage, the places of
    :func:`~camdegrade.fitting.in_chain.noise_places`) on the fit's evidence pairs (a
    :class:`~camdegrade.fitting.steps.PairedFit`), put the one :func:`_chosen_place` picks into ``fit.profile`` at
    its place, and return the record: its evidence, its place and every place's numbers."""
    places = noise_places(fit.profile, type(next(iter(candidates.values()))))

    def judge(pairs: Sequence[tuple[Tensor, Tensor]]) -> dict[str, tuple[Effect | None, NoiseEvidence]]:
        return {
            where: noise_evidence(
                fit.profile, stage, *zip(*pairs, strict=True), eight_bit=fit.eight_bit, insert=places[where]
            )
            for where, stage in candidates.items()
        }

    def measured(found: dict[str, tuple[Effect | None, NoiseEvidence]]) -> bool:
        return any(evidence.capture_noise is not None for _, evidence in found.values())

    judged, label = on_flat_pixels(fit, judge, measured)
    chosen = _chosen_place({where: evidence for where, (_, evidence) in judged.items()})
    stage, evidence = judged[chosen]
    if stage is not None:
        fit.profile = places[chosen](fit.profile, stage)
    numbers = {
        where: {
            "kept": item.kept,
            "noise_ratio_with": _rounded(item.noise_ratio_with),
            "correlation_with": _rounded(item.correlation_with),
            "distance": _rounded(place_distance(item)),
        }
        for where, (_, item) in judged.items()
    }
    where_line = "; ".join(f"{where}: distance {_number(n['distance'])}" for where, n in numbers.items())
    fit.say(
        f"effect {stage.name if stage else 'noise'}: {evidence.describe()} [evidence: {label}]; place {chosen} "
        f"({where_line})"
    )
    return {**evidence.to_dict(), "evidence": label, "place": chosen, "places": numbers}


def _chosen_place(judged: dict[str, NoiseEvidence]) -> str:
    """The first place (its own stage) unless the stage kept there comes out more correlated with the next pixel
    than the captures' noise by more than :data:`CORRELATION_MARGIN` (a resampler after it correlates it, and the
    captures' noise is whiter than that: added after the resize) or is not kept there; then the kept place nearest
    the captures (:func:`place_distance`). Where the captures' noise is as correlated as the resampler makes it, a
    stage after the resampler with correlated taps gives the same flat statistics, and the sensor's place is the
    physical one."""
    own, evidence = next(iter(judged.items()))
    excess = (
        None
        if evidence.correlation_with is None or evidence.correlation_capture is None
        else (evidence.correlation_with - evidence.correlation_capture)
    )
    if evidence.kept and (excess is None or excess <= CORRELATION_MARGIN):
        return own
    kept = [where for where, item in judged.items() if item.kept]
    return min(kept, key=lambda where: _or_inf(place_distance(judged[where]))) if kept else own


def place_distance(evidence: NoiseEvidence) -> float | None:
    """How far the profile with a noise stage is from the captures on flat pixels: ``|ln(noise ratio)|`` plus the
    difference of the noise's correlations with the next pixel (``None`` where either is not measured)."""
    ratio, ours, theirs = evidence.noise_ratio_with, evidence.correlation_with, evidence.correlation_capture
    if ratio is None or ratio <= 0 or ours is None or theirs is None:
        return None
    return abs(math.log(ratio)) + abs(ours - theirs)


def _or_inf(value: float | None) -> float:
    return math.inf if value is None else value


def _rounded(value: float | None) -> float | None:
    return None if value is None else round(value, 4)
