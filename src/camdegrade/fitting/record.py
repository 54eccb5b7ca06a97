"""What a fitted profile records of how it was made (``fitted``: the data used, the recipe, every step's evidence,
the machine) and of how close it came (``quality``), as strict JSON."""

from __future__ import annotations

import math
import platform
from collections.abc import Callable
from typing import Any

import torch

from camdegrade._profile_format.header import running_versions
from camdegrade._version import __version__
from camdegrade.fitting.recipe import FitConfig
from camdegrade.fitting.steps import STEPS, PairedFit
from camdegrade.pairs.pair import MISSING, UNREADABLE
from camdegrade.pairs.pairset import PairSet
from camdegrade.profile import CameraProfile

__all__ = ["finite_or_none", "fitted_record", "machine_record", "record_quality"]


def fitted_record(pairs: PairSet, fit: PairedFit, config: FitConfig) -> dict[str, Any]:
    """A paired fit's ``fitted`` metadata: the data used, the recipe, the best epoch, the machine, and every step's
    record (those the recipe leaves out by a toggle of the table too: not kept, and why)."""
    trained, val = fit.network, fit.val
    best = max(trained.history, key=lambda r: r.val_psnr if len(val) else -r.train_loss)
    left_out = {
        name: {
            "kept": False,
            "reason": "no network" if STEPS[name].needs_network and fit.profile.network is None else why,
        }
        for name, why in config.left_out().items()
    }
    return {
        "pairs": len(pairs),
        "skipped": len(pairs.report.skipped) if pairs.report is not None else 0,
        "unreadable": _unreadable(pairs),
        "train_pairs": len(fit.train),
        "validation_pairs": len(val),
        "validation_scenes": sorted(set(val.scenes)),
        "aligned": pairs.shifts is not None,
        "recipe": config.training_dict(),
        "best_epoch": best.epoch,
        "fit_minutes": round(trained.minutes, 2),
        **machine_record(),
        **left_out,
        **fit.records,
    }


def machine_record() -> dict[str, Any]:
    """The machine and the versions a profile was made with (as ``camdegrade info`` compares them)."""
    versions = running_versions()
    return {
        "machine": f"{platform.machine()}, {torch.get_num_threads()} threads, torch {torch.__version__}",
        "camdegrade": __version__,
        "torch": versions["torch"] or str(torch.__version__),
        "torchvision": versions["torchvision"],
    }


def record_quality(
    profile: CameraProfile, quality: dict[str, Any], warnings: list[str], say: Callable[[str], None]
) -> None:
    """Give a fitted profile its validation scores (strict JSON: :func:`finite_or_none`) and say every warning they
    raise, on the log and in ``profile.fitted['warnings']`` (absent when there is none)."""
    if warnings:
        profile.fitted["warnings"] = warnings
    for warning in warnings:
        say(f"warning: {warning}")
    profile.quality = finite_or_none(quality)


def finite_or_none(values: dict[str, Any]) -> dict[str, Any]:
    """``values`` with every non-finite number (the infinite PSNR of identical images) as ``None``, so that the
    metadata stays strict JSON (``null``)."""
    return {
        key: None if isinstance(value, float) and not math.isfinite(value) else value for key, value in values.items()
    }


def _unreadable(pairs: PairSet) -> list[dict[str, str]]:
    """The files skipped because they could not be read (truncated, too large, ...) or because a manifest names a
    file that does not exist: ``{"path", "reason"}`` (the CLI lists them and exits with status 1)."""
    skipped = pairs.report.skipped if pairs.report is not None else []
    failed = (UNREADABLE, MISSING)
    return [{"path": str(path), "reason": reason} for path, reason in skipped if reason.startswith(failed)]
