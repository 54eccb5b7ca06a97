"""Fitting a camera profile: from real (clean, captured) pairs (:func:`fit_profile`, a loop of steps:
:mod:`camdegrade.fitting.steps`), from the camera's own photos (:func:`fit_unpaired`), or from another profile
(:func:`distill_profile`); the network's training (:mod:`camdegrade.fitting.network`). The pairs themselves are
:mod:`camdegrade.pairs`' (their names are here too). See ``docs/fitting.md``."""

from camdegrade._support.recipes import DEFAULT_EFFECTS
from camdegrade.fitting.fit import fit_profile
from camdegrade.fitting.network.distill import distill_profile
from camdegrade.fitting.network.training import EpochResult, FitInterrupted, fit_network
from camdegrade.fitting.recipe import FitConfig
from camdegrade.fitting.unpaired import fit_unpaired
from camdegrade.pairs import (
    AlignmentResult,
    Pair,
    PairReport,
    PairSet,
    align_pair,
    apply_shift,
    discover_pairs,
    estimate_shift,
    filter_pairs,
    load_pair,
    register,
    split_by_scene,
)

__all__ = [
    "DEFAULT_EFFECTS",
    "AlignmentResult",
    "EpochResult",
    "FitConfig",
    "FitInterrupted",
    "Pair",
    "PairReport",
    "PairSet",
    "align_pair",
    "apply_shift",
    "discover_pairs",
    "distill_profile",
    "estimate_shift",
    "filter_pairs",
    "fit_network",
    "fit_profile",
    "fit_unpaired",
    "load_pair",
    "register",
    "split_by_scene",
]
