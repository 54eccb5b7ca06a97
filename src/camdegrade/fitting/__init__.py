"""Fitting a camera profile from real (clean, captured) pairs: pair discovery, the pair set, registration, the
network's training and checkpoints, and :func:`fit_profile` that runs them in order (``docs/fitting.md``)."""

from camdegrade.fitting.distill import distill_profile
from camdegrade.fitting.fit import DEFAULT_EFFECTS, fit_profile
from camdegrade.fitting.training import EpochResult, FitConfig, FitInterrupted, fit_network
from camdegrade.pairs.align import AlignmentResult, align_pair, apply_shift, estimate_shift, register
from camdegrade.pairs.discovery import discover_pairs, filter_pairs
from camdegrade.pairs.pair import Pair, PairReport
from camdegrade.pairs.pairset import PairSet, load_pair, split_by_scene

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
    "load_pair",
    "register",
    "split_by_scene",
]
