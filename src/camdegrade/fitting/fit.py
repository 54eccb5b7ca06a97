"""``fit_profile``: from a folder (or CSV, or suffix rule) of (clean, captured) pairs to a camera profile.

Steps: load the pair set (discover → load, EXIF honoured, unusable files reported) → split by scene into train and
validation → optionally register each pair → train the network (:mod:`camdegrade.fitting.training`) → fit the
effect stages the network cannot represent → a :class:`CameraProfile` whose metadata records how it was made.

References:
    Hegde et al., "A Simple Domain Shifting Network for Generating Low Quality Images" (the network and recipe).
"""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable, Iterable, Sequence
from typing import Any, Literal

import torch
import torch.distributed as dist

from camdegrade._distributed import is_main_process
from camdegrade._metadata import running_versions
from camdegrade._threads import torch_threads
from camdegrade._version import __version__
from camdegrade.effects import EFFECTS, STAGES, check_effect_names
from camdegrade.fitting.noise import CALIBRATION_PAIRS, fit_stage_in_chain
from camdegrade.fitting.pairs import MISSING, UNREADABLE
from camdegrade.fitting.pairset import PairSet, PairsSource, simulate
from camdegrade.fitting.training import (
    EpochResult,
    FitConfig,
    ImagePair,
    fit_network,
    resolve_recipe,
    training_dtype,
)
from camdegrade.metrics import psnr
from camdegrade.network import DomainShiftNet
from camdegrade.profile import CameraProfile, as_profile

__all__ = ["DEFAULT_EFFECTS", "fit_profile", "init_distributed_from_env", "is_main_process", "torch_threads"]

#: Effects fitted after the network by default. ``noise`` is always useful (an L2 network predicts the mean and
#: never the noise); position-dependent stages are kept only where they lower the validation error.
DEFAULT_EFFECTS: tuple[str, ...] = ("noise", "vignetting")
_MIN_RELATIVE_GAIN = 0.01

Log = Callable[[str], None]


def fit_profile(
    pairs: PairsSource,
    *,
    recipe: str | FitConfig = "fast",
    epochs: int | None = None,
    crop: int | None = None,
    batch_size: int | None = None,
    lr: float | None = None,
    lr_halving_epochs: int | None = None,
    crops_per_pair: int | None = None,
    patience: int | None = None,
    width: int | None = None,
    seed: int | None = None,
    val_fraction: float = 0.15,
    align: bool = False,
    clean_suffix: str | None = None,
    captured_suffix: str | None = None,
    strict: bool = False,
    size_mismatch: Literal["skip", "crop"] = "skip",
    effects: Iterable[str] = DEFAULT_EFFECTS,
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
    """Fit a camera profile from (clean, captured) pairs (see :class:`FitConfig` for the recipes).

    Args:
        pairs: a folder with ``clean/`` and ``captured/``, a folder plus ``clean_suffix``/``captured_suffix``, a
            CSV manifest, a list of :class:`~camdegrade.fitting.Pair`, a :class:`~camdegrade.fitting.PairReport`,
            or a list of ``(clean, captured)`` tensors.
        recipe: ``"fast"`` (default: a cosine schedule that stops early once the validation PSNR stops rising),
            ``"paper"`` (the paper's 100 epochs, lr 0.01 halved every 30) or a :class:`FitConfig`.
        epochs, crop, batch_size, lr, lr_halving_epochs, crops_per_pair, patience, width: change one value of the
            recipe; ``None`` keeps the recipe's. ``width`` is the network's (64, the paper's; 32 fits a network
            about four times cheaper to run).
        seed: initialisation, crops and the validation split (``None``: the recipe's, 0 unless a
            :class:`FitConfig` says otherwise).
        val_fraction: share of *scenes* held out for choosing the best epoch and checking the effect stages.
        align: register every pair (sub-pixel translation) before training; the shifts are logged.
        size_mismatch: pairs whose images differ in size are skipped, or with ``"crop"`` centre-cropped.
        effects: effect stages to fit after the network (names from ``EFFECTS``).
        init_from: start the network from this profile's network (a :class:`CameraProfile`, a built-in name or a
            path) instead of a fresh initialisation from ``seed``: a refit on new pairs, usually with fewer epochs
            and a lower ``lr`` (e.g. 20 and 0.001). Its width must be the recipe's (64 unless ``width`` says
            otherwise). Recorded in ``fitted['init_from']``.
        checkpoint: training state written after every epoch; with ``resume=True`` the fit continues from it.
        callback: called with an :class:`EpochResult` after every epoch (notebooks, Lightning loggers).
        log: called with human-readable progress lines (pairs found, shifts, effect fits).

    Returns:
        The fitted profile; its metadata records the pairs used, the recipe, validation PSNR and the machine.
    """
    say = log or (lambda message: None)
    changes = dict(epochs=epochs, crop=crop, batch_size=batch_size, lr=lr, lr_halving_epochs=lr_halving_epochs)
    changes.update(crops_per_pair=crops_per_pair, patience=patience, width=width, seed=seed)
    config = resolve_recipe(recipe, **changes)
    _check_arguments(pairs, device, name, description)
    effect_names = check_effect_names(effects)
    initial, init_label = _initial_network(init_from, config.width)
    with torch_threads(threads):
        pair_set = PairSet.load(
            pairs,
            clean_suffix=clean_suffix,
            captured_suffix=captured_suffix,
            strict=strict,
            size_mismatch=size_mismatch,
            log=say,
        )
        train, val = _split(pair_set, val_fraction, config.seed, align, say)
        if config.patience and not len(val):
            say("no validation pairs: the fit runs every epoch (early stopping needs validation)")
        started = time.perf_counter()
        network, history = fit_network(
            train.images,
            val.images,
            config,
            device=device,
            callback=callback,
            checkpoint=checkpoint,
            resume=resume,
            progress=progress,
            pair_names=[*train.names, *val.names],
            initial=initial,
        )
        minutes = (time.perf_counter() - started) / 60
        profile = CameraProfile(network, name=name, description=description)
        profile, effect_notes = _fit_effects(profile, [*val.unit_pairs(), *train.unit_pairs()], effect_names, say)
        profile.fitted = _record(pair_set, train, val, config, history, align, minutes, effect_notes)
        profile.fitted["init_from"] = init_label
        profile.fitted["trained_in"] = str(training_dtype(config.precision, torch.device(device))).split(".")[-1]
        profile.quality = _quality(profile, val) if len(val) else {}
        return profile


def _check_arguments(pairs: Any, device: Any, name: Any, description: Any) -> None:
    """What can be refused before any pair is read or any epoch trained."""
    if pairs is None:
        raise TypeError(
            "pairs must be a folder, a CSV manifest, a list of pairs or of (clean, captured) tensors, got None"
        )
    for label, text in (("name", name), ("description", description)):
        if not isinstance(text, str):
            raise TypeError(f"{label} must be a str, got {label}={text!r} ({type(text).__name__})")
    try:
        torch.empty(1, device=device)
    except Exception as error:  # a backend that is not built in may raise anything
        reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise ValueError(f"device must be a torch device usable here, got device={device!r} ({reason})") from None
    if torch.device(device).type == "meta":
        raise ValueError("device 'meta' holds no data, so nothing can be trained on it; use 'cpu' or 'cuda'")


def _split(pair_set: PairSet, val_fraction: float, seed: int, align: bool, say: Log) -> tuple[PairSet, PairSet]:
    """``(train, validation)`` split by scene (everything trains with one scene or ``val_fraction`` 0)."""
    if not 0.0 <= val_fraction < 1.0:
        raise ValueError(f"val_fraction must be in [0, 1), got val_fraction={val_fraction!r}")
    if val_fraction == 0 or len(set(pair_set.scenes)) < 2:
        train, val = pair_set, pair_set.subset([])
    else:
        train, val = pair_set.split(val_fraction, seed)
    if align:
        train, val = train.aligned(say), val.aligned(say)
    say(f"training on {len(train)} pairs, validating on {len(val)} ({len(set(val.scenes))} scenes)")
    return train, val


def _fit_effects(
    profile: CameraProfile, pairs: Sequence[ImagePair], names: Sequence[str], say: Log
) -> tuple[CameraProfile, dict[str, Any]]:
    """Fit each requested effect on (the profile's deterministic output, capture) over all pairs (noise needs many
    pixels; the network's residuals on its training crops are close to its validation residuals at 109k
    parameters), in the order light meets them; keep position-dependent stages only where they lower the error.
    Each is fitted by its class at its place in the chain (:meth:`Effect.fit_in_chain`: within its fitter's budget;
    noise calibrated through the stages already in the profile)."""
    notes: dict[str, Any] = {}
    cleans = [clean for clean, _ in pairs]
    captured = [target for _, target in pairs]
    for name in sorted(names, key=lambda n: STAGES.index(EFFECTS[n].stage)):
        kind = EFFECTS[name]
        simulated = simulate(profile, cleans, seed=0, deterministic=True)
        try:
            effect = fit_stage_in_chain(
                profile, kind, cleans, captured, calibration_pairs=CALIBRATION_PAIRS, sources=simulated
            )
        except ValueError as error:  # e.g. too few pixels to estimate it
            notes[name] = {"kept": False, "reason": str(error)}
            say(f"effect {name}: not fitted ({error})")
            continue
        if effect.position_dependent:
            before = _mean_squared_error(simulated, captured)
            with torch.no_grad():
                after = _mean_squared_error([effect(s[None])[0] for s in simulated], captured)
            gain = 1 - after / before if before > 0 else 0.0
            notes[name] = {"kept": gain >= _MIN_RELATIVE_GAIN, "relative_mse_gain": round(gain, 4)}
            say(f"effect {name}: relative MSE gain {gain:.2%} -> {'kept' if notes[name]['kept'] else 'dropped'}")
            if not notes[name]["kept"]:
                continue
        else:
            notes[name] = {"kept": True}
            say(f"effect {name}: fitted ({effect.extra_repr()})")
        profile = profile.with_effects(effect)
    return profile, notes


def _record(
    pair_set: PairSet,
    train: PairSet,
    val: PairSet,
    config: FitConfig,
    history: Sequence[EpochResult],
    align: bool,
    minutes: float,
    effect_notes: dict[str, Any],
) -> dict[str, Any]:
    """The ``fitted`` metadata: the data used, the recipe, the best epoch and the machine."""
    best = max(history, key=lambda r: r.val_psnr if len(val) else -r.train_loss)
    versions = running_versions()  # as `camdegrade info` compares them
    return {
        "pairs": len(pair_set),
        "skipped": len(pair_set.report.skipped) if pair_set.report is not None else 0,
        "unreadable": _unreadable(pair_set),
        "train_pairs": len(train),
        "validation_pairs": len(val),
        "validation_scenes": sorted(set(val.scenes)),
        "aligned": align,
        "recipe": config.as_dict(),
        "best_epoch": best.epoch,
        "fit_minutes": round(minutes, 2),
        "effects": effect_notes,
        "machine": f"{platform.machine()}, {torch.get_num_threads()} threads, torch {torch.__version__}",
        "camdegrade": __version__,
        "torch": versions["torch"] or str(torch.__version__),
        "torchvision": versions["torchvision"],
    }


def _initial_network(
    init_from: CameraProfile | str | os.PathLike[str] | None, width: int
) -> tuple[DomainShiftNet | None, str | None]:
    """The network ``init_from`` names (checked before any pair is loaded) and how the metadata records it: the name
    or path as given, or a profile object's name."""
    if init_from is None:
        return None, None
    if not isinstance(init_from, (CameraProfile, str, os.PathLike)):
        raise TypeError(
            f"init_from must be a CameraProfile, a profile name, a path or None, got {type(init_from).__name__}"
        )
    profile = as_profile(init_from)
    label = (profile.name or "(unnamed profile)") if isinstance(init_from, CameraProfile) else os.fspath(init_from)
    if profile.network is None:
        raise ValueError(f"init_from: profile {label!r} has no network to start from (it holds effect stages only)")
    if profile.network.width != width:
        raise ValueError(
            f"init_from: profile {label!r} has a network of width {profile.network.width}; this fit's width is "
            f"{width}, so it cannot start from it (pass width={profile.network.width})"
        )
    return profile.network, label


def _unreadable(pair_set: PairSet) -> list[dict[str, str]]:
    """The files skipped because they could not be read (truncated, too large, ...) or because a manifest names a
    file that does not exist: ``{"path", "reason"}`` (the CLI lists them and exits with status 1)."""
    skipped = pair_set.report.skipped if pair_set.report is not None else []
    failed = (UNREADABLE, MISSING)
    return [{"path": str(path), "reason": reason} for path, reason in skipped if reason.startswith(failed)]


def _mean_squared_error(predictions: Sequence[torch.Tensor], targets: Sequence[torch.Tensor]) -> float:
    total = sum(float(((p - t) ** 2).sum()) for p, t in zip(predictions, targets))
    return total / sum(t.numel() for t in targets)


def _quality(profile: CameraProfile, val: PairSet) -> dict[str, float]:
    """Validation PSNR of identity, network mean and the full (stochastic, seeded) profile against the captures."""
    identity, network, full = [], [], []
    sampled = simulate(profile, val.cleans(), seed=0, stream="quality")
    with torch.no_grad():
        for (clean, captured), sim in zip(val.unit_pairs(), sampled, strict=True):
            identity.append(psnr(clean, captured))
            network.append(psnr(profile.network(clean[None])[0], captured))
            full.append(psnr(sim, captured))
    return {
        "validation_pairs": len(val),
        "identity_psnr_db": round(sum(identity) / len(identity), 3),
        "network_psnr_db": round(sum(network) / len(network), 3),
        "profile_psnr_db": round(sum(full) / len(full), 3),
    }


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
