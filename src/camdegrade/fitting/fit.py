"""``fit_profile``: from a folder (or CSV, or suffix rule) of (clean, captured) pairs to a camera profile.

A fit is a loop of steps (:mod:`camdegrade.fitting.steps`): load the pair set (:class:`~camdegrade.pairs.PairSet`:
discovered, loaded, optionally registered; or loaded here from a path) → split it by scene into training and
validation pairs → run the recipe's steps in order, the network among them after the steps it is trained through
(each step proposes on the training pairs and is judged on the validation pairs; its evidence record goes to
``fitted[step.name]``) → record: a :class:`CameraProfile` whose metadata says how it was made and how close it comes
to the camera on the validation pairs (PSNR, fidelity, a critic), with a warning when the network does worse than
the identity or the linear baseline.

References:
    Hegde et al., "A Simple Domain Shifting Network for Generating Low Quality Images" (the network and recipe).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import torch
import torch.distributed as dist

from camdegrade._runtime.device import check_device
from camdegrade._runtime.distributed import is_main_process
from camdegrade._runtime.threads import torch_threads
from camdegrade.fitting.codec_warning import codec_warnings
from camdegrade.fitting.critic_warning import critic_warning
from camdegrade.fitting.network.training import EpochResult, training_dtype
from camdegrade.fitting.quality import fit_warnings, validation_quality
from camdegrade.fitting.recipe import FitConfig, resolve_recipe
from camdegrade.fitting.record import fitted_record, record_quality
from camdegrade.fitting.steps import PairedFit, run_steps
from camdegrade.fitting.steps.network import NetworkRun, NetworkStep, network_run
from camdegrade.pairs.pairset import PairSet, PairsSource
from camdegrade.profile import CameraProfile

__all__ = ["fit_profile", "init_distributed_from_env", "is_main_process", "torch_threads"]

Log = Callable[[str], None]


def fit_profile(
    pairs: PairsSource | PairSet,
    recipe: str | FitConfig = "fast",
    *,
    init_from: CameraProfile | str | os.PathLike[str] | None = None,
    device: torch.device | str = "cpu",
    threads: int | None = None,
    checkpoint: str | os.PathLike[str] | None = None,
    resume: bool = False,
    callback: Callable[[EpochResult], None] | None = None,
    progress: bool = False,
    name: str = "",
    description: str = "",
    log: Log | None = None,
) -> CameraProfile:
    """Fit a camera profile from (clean, captured) pairs with a recipe::

        fit_profile("pairs/")
        fit_profile(PairSet.load("pairs/", clean_suffix="_mean", captured_suffix="_real", align=True),
                    FitConfig.recipe("fast").replace(epochs=3, effects=()))

    Args:
        pairs: a :class:`~camdegrade.fitting.PairSet` (loaded with its options: suffixes, ``strict``,
            ``size_mismatch``, ``max_pairs``, ``align``; see :meth:`PairSet.load`), or what it loads with the default
            options: a folder with ``clean/`` and ``captured/``, a CSV manifest, a
            :class:`~camdegrade.fitting.PairReport`, a list of :class:`~camdegrade.fitting.Pair` or of
            ``(clean, captured)`` tensors.
        recipe: ``"fast"`` (default: a cosine schedule that stops early once the validation PSNR stops rising),
            ``"paper"`` (the paper's 100 epochs, lr 0.01 halved every 30) or a :class:`FitConfig`: every training
            value, the seed (initialisation, crops and the split), the share of scenes that validates
            (``val_fraction``) and the steps run besides the network (``steps``: the sensor resolution, the effect
            stages, the texture, noise reduction and detail response that match the captures).
        init_from: start the network from this profile's network (a :class:`CameraProfile`, a built-in name or a
            path) instead of a fresh initialisation from the recipe's seed: a refit on new pairs, usually with fewer
            epochs and a lower ``lr`` (e.g. 20 and 0.001). Its width must be the recipe's. Recorded in
            ``fitted['init_from']``. The fit keeps that network's architecture (``arch``).
        checkpoint: training state written after every epoch; with ``resume=True`` the fit continues from it.
        callback: called with an :class:`EpochResult` after every epoch (notebooks, Lightning loggers).
        log: called with human-readable progress lines (pairs found, shifts, each step's evidence, warnings).

    Returns:
        The fitted profile; its metadata records the pairs used, the recipe, each step with the evidence it was kept
        or dropped on (``fitted['resolution']``, ``fitted['network']``, ``fitted['effects']``, ...), the validation
        PSNR of the identity, the linear baseline, the network and the profile (strict JSON: a PSNR of identical
        images is ``null``), its fidelity (``quality['fidelity']``: grid, bands, flat noise, critic accuracy with and
        without the clean source) and ``fitted['warnings']`` when the network does worse than the identity or the
        baseline on the validation pairs (also logged; see :func:`~camdegrade.fitting.quality.quality_warnings`) or
        when its validation image-only critic tells the sampled profile from the captures
        (:mod:`~camdegrade.fitting.critic_warning`: the statistics that differ most, the diagnose command). A
        network (or linear baseline) that beats the clean image passed through unchanged by less than
        :data:`~camdegrade.fitting.steps.network.NETWORK_MIN_GAIN_DB` on the validation pairs is dropped: the profile
        then holds its effect stages only, fitted on the clean images, with a colour stage where the pairs show a
        significant shift between the channels (:mod:`~camdegrade.fitting.colour_shift`, ``fitted['effects']
        ['color']``); ``fitted['network']`` records the gains it was judged on.
    """
    say = log or _silent
    config = resolve_recipe(recipe)
    _check_arguments(pairs, name, description)
    check_device(device)
    how = {"device": device, "checkpoint": checkpoint, "resume": resume, "callback": callback, "progress": progress}
    run, config = network_run(init_from, config, **how)
    with torch_threads(threads):
        pair_set = pairs if isinstance(pairs, PairSet) else PairSet.load(pairs, log=say)
        fit = _split(pair_set, config, run, CameraProfile(None, name=name, description=description), say)
        run_steps(config.steps_with(NetworkStep(config, run)), fit)
        return _recorded(fit, pair_set, config, run)


def _silent(message: str) -> None:
    pass


def _check_arguments(pairs: Any, name: Any, description: Any) -> None:
    """What can be refused before any pair is read or any epoch trained."""
    if pairs is None:
        raise TypeError(
            "pairs must be a folder, a CSV manifest, a list of pairs or of (clean, captured) tensors, got None"
        )
    for label, text in (("name", name), ("description", description)):
        if not isinstance(text, str):
            raise TypeError(f"{label} must be a str, got {label}={text!r} ({type(text).__name__})")


def _split(pair_set: PairSet, config: FitConfig, run: NetworkRun, start: CameraProfile, say: Log) -> PairedFit:
    """The fit of ``pair_set`` split by scene (a share ``config.val_fraction`` of the scenes validates, seeded), at
    the profile ``start``."""
    train, val = pair_set.validation_split(config.val_fraction, config.seed)
    say(f"training on {len(train)} pairs, validating on {len(val)} ({len(set(val.scenes))} scenes)")
    if config.patience and not len(val):
        say("no validation pairs: the fit runs every epoch (early stopping needs validation)")
    refit = run.initial is not None
    return PairedFit.of(pair_set, train, val, profile=start, seed=config.seed, say=say, arch=config.arch, refit=refit)


def _recorded(fit: PairedFit, pair_set: PairSet, config: FitConfig, run: NetworkRun) -> CameraProfile:
    """The fitted profile with its records: how it was made (``fitted``) and its validation scores (``quality``)."""
    profile, trained = fit.profile, fit.network
    profile.fitted = fitted_record(pair_set, fit, config)
    profile.fitted["init_from"] = run.label
    profile.fitted["trained_in"] = str(training_dtype(config.precision, torch.device(run.device))).split(".")[-1]
    scores = trained.scores
    quality = validation_quality(profile, scores, fit.val, fit.eight_bit, fit.say) if scores is not None else {}
    warnings = fit_warnings(quality, trained.history, config, trained.kept)
    warnings += codec_warnings(fit.records) + critic_warning(quality.get("fidelity"), _pairs_path(pair_set))
    record_quality(profile, quality, warnings, fit.say)
    return profile


def _pairs_path(pair_set: PairSet) -> str | None:
    """The folder or manifest the pairs were found in, as the user gave it (``None``: tensors or pairs in memory)."""
    source = pair_set.report.source if pair_set.report is not None else None
    return os.fspath(source) if isinstance(source, (str, os.PathLike)) else None


def init_distributed_from_env(device: torch.device | str = "cpu") -> torch.device:
    """Join the process group ``torchrun`` describes in the environment (gloo on CPU, NCCL on CUDA).

    Returns the device this process should train on: with CUDA, each process takes the GPU of its
    ``LOCAL_RANK``. Outside ``torchrun`` (no ``WORLD_SIZE`` > 1) nothing is joined and ``device`` is returned.
    """
    device = torch.device(device)
    if int(os.environ.get("WORLD_SIZE", "1")) <= 1 or not dist.is_available():
        return device
    if device.type == "cuda":
        device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
        torch.cuda.set_device(device)
    if not dist.is_initialized():
        dist.init_process_group(backend="nccl" if device.type == "cuda" else "gloo")
    return device
