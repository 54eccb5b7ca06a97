"""Measures of a camera's degradation shared by fitting and diagnosis (it imports neither): the statistic families
in one registry (:mod:`camdegrade.measures.base`: what each measures, its tau, its description, which effects and
which network faults it signals), the sets and the gap built on them, the learned critic, and the fidelity of a
simulation to the camera read from the images (:mod:`camdegrade.measures.fidelity`: grid, texture bands, flat
noise) and what a person sees of them, judged against their spread (:mod:`camdegrade.measures.visible`: the
4-pixel grid, texture too smooth or too sharp), and the AKLD of simulated against real noise
(:mod:`camdegrade.measures.akld`).

The modules below are imported in the order the families are registered (the order of every report).
"""

from camdegrade.measures.families import spatial, intensity, noise, frequency, blocks, color, alignment, comb  # noqa: F401, I001
from camdegrade.measures.families import no_reference  # noqa: F401
from camdegrade.measures.akld import akld
from camdegrade.measures.base import (
    FAMILIES,
    NO_REFERENCE,
    Family,
    MeasuredPair,
    NoReferenceFamily,
    PairedFamily,
    check_explains,
    register_family,
)
from camdegrade.measures.fidelity import (
    BAND_EDGES,
    FidelityReport,
    band_log2_ratios,
    grid_rms,
    measure_fidelity,
    noise_ratios,
)
from camdegrade.measures.gap import bootstrap_indices, family_gaps, gap, gap_spread, measurement_scale
from camdegrade.measures.statistics import StatisticSet, image_statistics, pair_statistics

__all__ = [
    "BAND_EDGES",
    "FAMILIES",
    "NO_REFERENCE",
    "Family",
    "FidelityReport",
    "MeasuredPair",
    "NoReferenceFamily",
    "PairedFamily",
    "StatisticSet",
    "akld",
    "band_log2_ratios",
    "bootstrap_indices",
    "check_explains",
    "family_gaps",
    "gap",
    "gap_spread",
    "grid_rms",
    "image_statistics",
    "measure_fidelity",
    "measurement_scale",
    "noise_ratios",
    "pair_statistics",
    "register_family",
]
