"""``fit_profile``: from a folder (or CSV, or suffix rule) of (clean, captured) pairs to a camera profile.

Steps: discover pairs → load (EXIF honoured) → optionally register each pair → split by scene into train and
validation → train the network (:mod:`camdegrade.training`) → fit the effect stages the network cannot represent
on the validation residuals → a :class:`CameraProfile` whose metadata records how it was made.
"""

from __future__ import annotations

import contextlib
import os
import platform
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, Literal

import torch
import torch.distributed as dist

from camdegrade._version import __version__
from camdegrade.align import align_pair, format_shifts
from camdegrade.effects import EFFECTS, STAGES, Effect
from camdegrade.metrics import psnr
from camdegrade.pairs import Pair, PairReport, discover_pairs, load_pair, split_by_scene
from camdegrade.profile import CameraProfile
from camdegrade.training import EpochResult, FitConfig, ImagePair, fit_network

#: Effects fitted after the network by default. ``noise`` is always useful (an L2 network predicts the mean and
#: never the noise); position-dependent stages are kept only where they lower the validation error.
DEFAULT_EFFECTS: tuple[str, ...] = ("noise", "vignetting")
_POSITION_EFFECTS = frozenset({"vignetting", "chromatic_aberration", "distortion"})
_MIN_RELATIVE_GAIN = 0.01


def fit_profile(
    pairs: str | os.PathLike[str] | Sequence[Pair] | PairReport,
    *,
    epochs: int = 100,
    crop: int = 128,
    batch_size: int = 32,
    lr: float = 0.01,
    lr_halving_epochs: int = 30,
    crops_per_pair: int = 8,
    seed: int = 0,
    val_fraction: float = 0.15,
    align: bool = False,
    clean_suffix: str | None = None,
    captured_suffix: str | None = None,
    strict: bool = False,
    size_mismatch: Literal["skip", "crop"] = "skip",
    effects: Iterable[str] = DEFAULT_EFFECTS,
    device: torch.device | str = "cpu",
    threads: int | None = None,
    checkpoint: str | os.PathLike[str] | None = None,
    resume: bool = False,
    callback: Callable[[EpochResult], None] | None = None,
    progress: bool = False,
    name: str = "",
    description: str = "",
    log: Callable[[str], None] | None = None,
) -> CameraProfile:
    """Fit a camera profile from (clean, captured) pairs with the paper's recipe (see :class:`FitConfig`).

    Args:
        pairs: a folder with ``clean/`` and ``captured/``, a folder plus ``clean_suffix``/``captured_suffix``, a
            CSV manifest, a list of :class:`~camdegrade.pairs.Pair`, or a :class:`~camdegrade.pairs.PairReport`.
        val_fraction: share of *scenes* held out for choosing the best epoch and fitting the effect stages.
        align: register every pair (sub-pixel translation) before training; the shifts are logged.
        size_mismatch: pairs whose images differ in size are skipped, or with ``"crop"`` centre-cropped.
        effects: effect stages to fit after the network on validation residuals (names from ``EFFECTS``).
        checkpoint: training state written after every epoch; with ``resume=True`` the fit continues from it.
        callback: called with an :class:`EpochResult` after every epoch (notebooks, Lightning loggers).
        log: called with human-readable progress lines (pairs found, shifts, effect fits).

    Returns:
        The fitted profile; its metadata records the pairs used, the recipe, validation PSNR and the machine.
    """
    say = log or (lambda message: None)
    config = FitConfig(
        epochs=epochs,
        crop=crop,
        batch_size=batch_size,
        lr=lr,
        lr_halving_epochs=lr_halving_epochs,
        crops_per_pair=crops_per_pair,
        seed=seed,
    )
    effect_names = _check_effect_names(effects)
    with torch_threads(threads):
        report = _as_report(
            pairs,
            clean_suffix=clean_suffix,
            captured_suffix=captured_suffix,
            strict=strict,
            size_mismatch=size_mismatch,
        )
        say(report.summary())
        train_pairs, val_pairs = _split(report.pairs, val_fraction, seed)
        train = _load(train_pairs, align, say)
        val = _load(val_pairs, align, say)
        say(f"training on {len(train)} pairs, validating on {len(val)} ({len({p.scene for p in val_pairs})} scenes)")
        started = time.perf_counter()
        network, history = fit_network(
            train,
            val,
            config,
            device=device,
            callback=callback,
            checkpoint=checkpoint,
            resume=resume,
            progress=progress,
        )
        minutes = (time.perf_counter() - started) / 60
        profile = CameraProfile(network, name=name, description=description)
        profile, effect_notes = _fit_effects(profile, [*val, *train], effect_names, say)
        best = max(history, key=lambda r: r.val_psnr if val else -r.train_loss)
        profile.fitted = {
            "pairs": len(report.pairs),
            "skipped": len(report.skipped),
            "train_pairs": len(train),
            "validation_pairs": len(val),
            "validation_scenes": sorted({p.scene for p in val_pairs}),
            "aligned": align,
            "recipe": config.as_dict(),
            "best_epoch": best.epoch,
            "fit_minutes": round(minutes, 2),
            "effects": effect_notes,
            "machine": f"{platform.machine()}, {torch.get_num_threads()} threads, torch {torch.__version__}",
            "camdegrade": __version__,
        }
        profile.quality = _quality(profile, val) if val else {}
        return profile


@contextlib.contextmanager
def torch_threads(threads: int | None) -> Iterator[None]:
    """Run the block with ``threads`` torch threads (unchanged when None), then restore the previous count."""
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 1):
        raise ValueError(f"threads must be a positive integer or None, got threads={threads!r}")
    previous = torch.get_num_threads()
    if threads is not None:
        torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def _check_effect_names(effects: Iterable[str]) -> list[str]:
    names = list(effects)
    unknown = [name for name in names if name not in EFFECTS]
    if unknown:
        raise ValueError(f"effects must be names from {sorted(EFFECTS)}, got unknown {unknown}")
    return names


def _as_report(pairs, **discovery: Any) -> PairReport:
    if isinstance(pairs, PairReport):
        return pairs
    if isinstance(pairs, (str, os.PathLike)):
        return discover_pairs(Path(pairs), **discovery)
    pairs = list(pairs)
    if not all(isinstance(pair, Pair) for pair in pairs):
        raise TypeError("pairs must be a path, a PairReport or a list of camdegrade.pairs.Pair")
    return PairReport(pairs=pairs, skipped=[])


def _split(pairs: Sequence[Pair], val_fraction: float, seed: int) -> tuple[list[Pair], list[Pair]]:
    if not 0.0 <= val_fraction < 1.0:
        raise ValueError(f"val_fraction must be in [0, 1), got val_fraction={val_fraction!r}")
    if val_fraction == 0 or len({pair.scene for pair in pairs}) < 2:
        return list(pairs), []
    train, val = split_by_scene(pairs, val_fraction, seed=seed)
    return list(train), list(val)


def _load(pairs: Sequence[Pair], align: bool, say: Callable[[str], None]) -> list[ImagePair]:
    loaded, shifts = [], {}
    for pair in pairs:
        clean, captured = load_pair(pair)
        if align:
            clean, captured, shifts[pair.name] = align_pair(clean, captured)
        loaded.append((clean, captured))
    if shifts:
        say(format_shifts(shifts))
    return loaded


def _unit(image: torch.Tensor) -> torch.Tensor:
    return image.float().div(255.0)


def _fit_effects(
    profile: CameraProfile, pairs: Sequence[ImagePair], names: Sequence[str], say: Callable[[str], None]
) -> tuple[CameraProfile, dict[str, Any]]:
    """Fit each requested effect on (profile output, capture) over all pairs (noise needs many pixels; the network's
    residuals on its training crops are close to its validation residuals at 109k parameters); keep
    position-dependent stages only where they lower the error."""
    notes: dict[str, Any] = {}
    captured = [_unit(target) for _, target in pairs]
    for name in sorted(names, key=lambda n: STAGES.index(EFFECTS[n].stage)):  # fit in the order light meets them
        simulated = [_simulate(profile, _unit(clean)) for clean, _ in pairs]
        try:
            effect: Effect = EFFECTS[name].fit(simulated, captured)
        except ValueError as error:  # e.g. too few pixels to estimate it
            notes[name] = {"kept": False, "reason": str(error)}
            say(f"effect {name}: not fitted ({error})")
            continue
        if name in _POSITION_EFFECTS:
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


def _simulate(profile: CameraProfile, image: torch.Tensor) -> torch.Tensor:
    """The profile's output for one (3, H, W) image, with its random stages drawn from a fixed seed."""
    batch = image[None]
    with torch.no_grad():
        return profile(batch, profile.make_params(batch.shape, torch.Generator().manual_seed(0)))[0]


def _mean_squared_error(predictions: Sequence[torch.Tensor], targets: Sequence[torch.Tensor]) -> float:
    total = sum(float(((p - t) ** 2).sum()) for p, t in zip(predictions, targets))
    return total / sum(t.numel() for t in targets)


def _quality(profile: CameraProfile, val: Sequence[ImagePair]) -> dict[str, float]:
    """Validation PSNR of identity, network mean and the full (stochastic, seeded) profile against the captures."""
    identity, network, full = [], [], []
    generator = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for clean, captured in val:
            image = _unit(clean)[None]
            identity.append(psnr(clean, captured))
            network.append(psnr(profile.network(image)[0], _unit(captured)))
            params = profile.make_params(image.shape, generator)
            full.append(psnr(profile(image, params)[0], _unit(captured)))
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


def is_main_process() -> bool:
    return not (dist.is_available() and dist.is_initialized()) or dist.get_rank() == 0
