"""The ``comb`` family: how combed the histogram of 8-bit codes is (a buffer of few levels, a posterised image).

A buffer of few bits, or one quantized before a tone table, leaves the output holding only some codes: its
histogram is a comb (a 5-bit buffer: one code in eight occupied), where a photo's, dithered by its noise and spread
by its content, is smooth at the scale of a few codes. No texture makes a comb: content moves the histogram's
envelope, not every other code. The statistic rests on every pixel of every pair (their codes' counts summed over
pairs, each code's local mean at least :data:`~camdegrade.functional.isp.quantization.MIN_COUNT` pixels).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar

import torch
from torch import Tensor

from camdegrade.functional.isp.quantization import MIN_COUNT, code_histogram, histogram_comb
from camdegrade.measures.base import MeasuredPair, PairedFamily, register_family

if TYPE_CHECKING:
    from camdegrade.measures.statistics import StatisticSet

__all__ = ["MIN_MEASURED_CODES", "Comb"]

#: The comb is measured where at least this many codes per channel are (a histogram spread over 32 codes, and
#: 32 × :data:`~camdegrade.functional.isp.quantization.MIN_COUNT` pixels at least).
MIN_MEASURED_CODES = 32


@register_family
class Comb(PairedFamily):
    """Per channel, ``Σ|h − local mean| / Σ local mean`` of the 8-bit code histogram ``h`` summed over the pairs
    (local mean: 9 codes): 0 smooth, 0.2 for an 8-bit buffer through a contrast table, 1.7 for a 5-bit buffer."""

    name = "comb"
    #: On the log scale (:meth:`compare`): a comb 1.5× another's is one unit.
    tau = 0.4
    #: Combs below this are compared as this: the Poisson scatter of the counts alone combs a histogram by 0.02–0.05
    #: (12–40 pairs of 96²–128²), and on the log scale its chance differences would count for up to a unit.
    FLOOR: ClassVar[float] = 0.05
    unit = "log histogram comb"
    description = "comb of the 8-bit code histogram: log Σ|h − mean of 9 codes| / Σ mean, per channel, all pixels"

    def measure(self, pair: MeasuredPair) -> tuple[Tensor, Tensor]:
        histogram = code_histogram(pair.image)
        return histogram.flatten().float(), histogram.sum(-1).float()

    def reduce(self, num: Tensor, den: Tensor) -> Tensor:
        comb, mean = histogram_comb(num.reshape(3, 256))
        enough = mean >= MIN_MEASURED_CODES * MIN_COUNT
        return torch.where(enough, comb / mean.clamp_min(1e-12), torch.full_like(comb, float("nan")))

    def compare(self, values: Tensor) -> Tensor:
        return values.clamp_min(self.FLOOR).log()

    def describe(self, real: Tensor, sim: Tensor, real_set: StatisticSet) -> str:
        if not bool(torch.isfinite(real).any()):
            return "histogram comb not measurable: too few pixels per 8-bit code"
        pixels = int(real_set.sums[self.name][1].sum(0)[0])
        return (
            f"8-bit code histogram comb (0 smooth, 1.7 for a 5-bit buffer): real {float(real.nanmean()):.2f} vs sim "
            f"{float(sim.nanmean()):.2f}, on {pixels} pixels per channel"
        )
