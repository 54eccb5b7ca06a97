"""Real (clean, captured) pairs, under both workflows (fitting and diagnosis): discovery (files → a report of what
was found and skipped), the pair set (loaded, registered, split by scene), alignment, and the one reader of a
folder of images."""

from camdegrade.pairs.align import AlignmentResult, align_pair, apply_shift, estimate_shift, register
from camdegrade.pairs.discovery import discover_pairs, filter_pairs
from camdegrade.pairs.folder import FolderImages, read_folder
from camdegrade.pairs.pair import Pair, PairReport
from camdegrade.pairs.pairset import PairSet, PairsSource, load_pair, split_by_scene

__all__ = [
    "AlignmentResult",
    "FolderImages",
    "Pair",
    "PairReport",
    "PairSet",
    "PairsSource",
    "align_pair",
    "apply_shift",
    "discover_pairs",
    "estimate_shift",
    "filter_pairs",
    "load_pair",
    "read_folder",
    "register",
    "split_by_scene",
]
