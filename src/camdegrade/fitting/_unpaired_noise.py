"""Camera noise fitted from the captures alone: each capture's own flat regions, no clean reference.

Where a capture is flat (:func:`~camdegrade.functional.analysis.flat_mask` of the capture itself: at a Gaussian
derivative of 2 px the noise barely moves the gradient), its residual from the 17×17 local mean is its noise,
binned by that local mean (:class:`~camdegrade.functional.noise_stats.NoiseSums`: level per channel and intensity
bin, lag-1/2 and channel correlation, row and column line means). The same measurement of the clean set, run
through the rest of the fitted chain, is the base (what the clean images carry already); the noise stage then
follows by simulated moments (:func:`~camdegrade.effects._noise_fit.calibrate`), so clipping, the tone curve,
sharpening and the codec after the noise are absorbed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from torch import Tensor

from camdegrade.effects import Noise
from camdegrade.effects._noise_fit import calibrate, check_measurable, initial_noise
from camdegrade.functional.analysis import box_mean, flat_mask
from camdegrade.functional.noise_stats import HIGH_PASS, NoiseSums

#: A noise stage is kept when its std at mid-grey is at least this many 8-bit levels (8-bit rounding alone leaves
#: about 0.3).
NOISE_FLOOR = 0.5
#: ... and when the captures' flat pixels vary at least this much more than the simulated clean set's without it
#: (the rest is the two sets' content, not noise).
NOISE_SHARE = 1.1


def flat_sums(images: Sequence[Tensor]) -> NoiseSums:
    """The noise sums of each image on its own flat pixels, binned by its own local mean."""
    total = NoiseSums.zeros()
    for image in images:
        total = total + NoiseSums.measure(image, box_mean(image, HIGH_PASS), flat_mask(image))
    return total


def fit_noise_unpaired(
    real: NoiseSums,
    simulate: Callable[[Noise | None], list[Tensor]],
    *,
    taps: int = 5,
    banding: bool = True,
    rounds: int = 2,
) -> tuple[Noise | None, dict]:
    """The noise stage whose simulation on the clean set matches ``real`` (the captures' :func:`flat_sums`).

    ``simulate(noise)`` runs the clean set through the fitted chain with ``noise`` in place (``None``: without
    noise; fixed seeds). Returns the stage (``None`` below :data:`NOISE_FLOOR` or :data:`NOISE_SHARE`) and notes
    for the metadata.

    References:
        A. Foi, M. Trimeche, V. Katkovnik, K. Egiazarian, "Practical Poissonian-Gaussian noise modeling and fitting
        for single-image raw-data", IEEE Transactions on Image Processing 17(10), 2008 (noise level per intensity
        from a single image's smooth regions).
    """
    check_measurable(real)
    base = flat_sums(simulate(None))
    start = initial_noise(Noise, real, base, taps)
    noise = calibrate(start, simulate, flat_sums, real, base, rounds=rounds, banding=banding)
    level = noise.magnitude()
    notes = {
        "std_mid_grey_levels": round(level, 3),
        "flat_pixels": real.pixels,
        "captures_std_levels": _rounded(real.pooled_std()),
        "clean_std_levels": _rounded(base.pooled_std()),
    }
    kept = level >= NOISE_FLOOR and real.pooled_std() >= NOISE_SHARE * base.pooled_std()
    return (noise if kept else None), notes


def _rounded(value: float) -> float | None:
    return round(value, 3) if value == value else None
