"""The noise stage of a profile, fitted where it sits in the chain: :meth:`Noise.fit` against the profile's
deterministic output, then calibrated by simulating the whole profile with it (the stages after the sensor —
tone, codec — change the noise the captures show)."""

from __future__ import annotations

from collections.abc import Sequence

from torch import Tensor

from camdegrade.effects import Noise
from camdegrade.effects._noise_fit import calibrate
from camdegrade.fitting.pairset import simulate
from camdegrade.functional.analysis import flat_mask
from camdegrade.functional.noise_stats import NoiseSums
from camdegrade.profile import CameraProfile


def fit_noise_stage(
    profile: CameraProfile,
    cleans: Sequence[Tensor],
    captures: Sequence[Tensor],
    *,
    seed: int = 0,
    rounds: int = 2,
    banding: bool = True,
    calibration_pairs: int | None = None,
) -> Noise:
    """A noise stage for ``profile`` (any noise stage it has is replaced): fitted on ``(profile's deterministic
    output, capture)`` pairs, then corrected until the profile with it reproduces the captures' noise statistics
    on flat pixels (measured on at most ``calibration_pairs`` evenly spaced pairs; all by default)."""
    centre = profile.without_randomness()
    sources = simulate(centre, cleans, seed, stream="noise-sources")
    start = Noise.fit(sources, list(captures), estimator="excess", rounds=0, banding=False, seed=seed)
    step = max(1, len(cleans) // calibration_pairs) if calibration_pairs else 1
    cleans, captures, sources = list(cleans)[::step], list(captures)[::step], sources[::step]
    masks = [flat_mask(clean) for clean in cleans]

    def measure(images: list[Tensor]) -> NoiseSums:
        total = NoiseSums.zeros()
        for image, clean, mask in zip(images, cleans, masks, strict=True):
            total = total + NoiseSums.measure(image, clean, mask)
        return total

    def with_noise(noise: Noise) -> list[Tensor]:
        return simulate(replace_noise(profile, noise), cleans, seed, stream="noise-calibration")

    return calibrate(
        start, with_noise, measure, measure(list(captures)), measure(sources), rounds=rounds, banding=banding
    )


def replace_noise(profile: CameraProfile, noise: Noise) -> CameraProfile:
    """``profile`` with ``noise`` in place of its noise stages (inserted at the sensor stage)."""
    return profile.with_chain([e for e in profile.effects if not isinstance(e, Noise)]).with_effects(noise)
