"""``fit_profile``: from a folder (or CSV, or suffix rule) of (clean, captured) pairs to a camera profile.

Steps: a pair set (:class:`~camdegrade.fitting.PairSet`: discovered, loaded, optionally registered; or loaded here
from a path) → split by scene into train and validation → train the network (:mod:`camdegrade.fitting.training`)
→ fit the effect stages the network cannot represent on the training pairs, keeping those the validation pairs show
the camera has (:mod:`camdegrade.fitting.stages`) → a :class:`CameraProfile` whose metadata records how it was made
and how close it comes to the camera on the validation pairs (PSNR, fidelity, a critic), with a warning when the
network does worse than the identity or the linear baseline.

References:
    Hegde et al., "A Simple Domain Shifting Network for Generating Low Quality Images" (the network and recipe).
"""

from __future__ import annotations

import math
import os
import platform
import time
from collections.abc import Callable, Sequence
from typing import Any

import torch
import torch.distributed as dist

from camdegrade._device import check_device
from camdegrade._distributed import is_main_process
from camdegrade._profile_format.header import running_versions
from camdegrade._recipes import FAST
from camdegrade._threads import torch_threads
from camdegrade._version import __version__
from camdegrade.effects import Color, Resolution
from camdegrade.fitting.baseline import baseline_psnr, fit_linear_baseline
from camdegrade.fitting.colour_shift import keep_colour_shift
from camdegrade.fitting.evidence import as_stored
from camdegrade.fitting.faint_detail import fit_denoise
from camdegrade.fitting.pairs import MISSING, UNREADABLE
from camdegrade.fitting.pairset import PairSet, PairsSource, simulate
from camdegrade.fitting.resolution import find_sensor
from camdegrade.fitting.response import fit_response
from camdegrade.fitting.stages import fit_effects
from camdegrade.fitting.texture import fit_texture
from camdegrade.fitting.training import (
    EpochResult,
    FitConfig,
    fit_network,
    new_network,
    resolve_recipe,
    training_dtype,
)
from camdegrade.measures.critic import repeated_critic_test
from camdegrade.measures.fidelity import measure_fidelity
from camdegrade.metrics import psnr
from camdegrade.network import LocalAffineNet, ShiftNetwork
from camdegrade.profile import CameraProfile, as_profile

__all__ = [
    "DEFAULT_EFFECTS",
    "finite_or_none",
    "fit_profile",
    "init_distributed_from_env",
    "is_main_process",
    "quality_warnings",
    "torch_threads",
]

#: Effects fitted after the network by default (the recipes' ``effects``), each kept only where the validation pairs
#: show that the camera has it (:mod:`camdegrade.fitting.evidence`): an L2 network predicts the mean and never the
#: noise, but a noiseless camera must get no noise stage.
DEFAULT_EFFECTS: tuple[str, ...] = FAST["effects"]

Log = Callable[[str], None]
ImagePair = tuple[torch.Tensor, torch.Tensor]


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
            (``val_fraction``) and the effect stages fitted after the network (``effects``).
        init_from: start the network from this profile's network (a :class:`CameraProfile`, a built-in name or a
            path) instead of a fresh initialisation from the recipe's seed: a refit on new pairs, usually with fewer
            epochs and a lower ``lr`` (e.g. 20 and 0.001). Its width must be the recipe's. Recorded in
            ``fitted['init_from']``. The fit keeps that network's architecture (``arch``).
        checkpoint: training state written after every epoch; with ``resume=True`` the fit continues from it.
        callback: called with an :class:`EpochResult` after every epoch (notebooks, Lightning loggers).
        log: called with human-readable progress lines (pairs found, shifts, effect fits, warnings).

    Returns:
        The fitted profile; its metadata records the pairs used, the recipe, each effect stage tried with the
        evidence it was kept or dropped on (``fitted['effects']``), the validation PSNR of the identity, the linear
        baseline, the network and the profile (strict JSON: a PSNR of identical images is ``null``), its fidelity
        (``quality['fidelity']``: grid, bands, flat noise, critic accuracy with and without the clean source) and
        ``fitted['warnings']`` when the network does worse than the identity or the baseline on the validation pairs
        (also logged; see :func:`quality_warnings`). A network (or linear baseline) that beats the clean image
        passed through unchanged by less than :data:`NETWORK_MIN_GAIN_DB` on the validation pairs is dropped: the
        profile holds its effect stages only, fitted on the clean images, and a colour stage for a significant shift
        between the channels (:mod:`~camdegrade.fitting.colour_shift`; ``fitted['network']``: the gains judged).
    """
    say = log or _silent
    config = resolve_recipe(recipe)
    _check_arguments(pairs, name, description)
    check_device(device)
    initial, init_label = _initial_network(init_from, config)
    if initial is not None and config.sensor_scale not in ("auto", 1, 1.0):
        raise ValueError(
            f"sensor_scale={config.sensor_scale} trains a new network through the sensor; init_from continues a "
            "network as it was trained: pass one or the other"
        )
    if initial is not None:  # a refit continues the network it starts from, whatever the recipe's default
        config = config.replace(
            arch=initial.arch,
            upsample=getattr(initial, "upsample", None),
            curves="channel" if getattr(initial, "curves", False) else "none",
        )
    with torch_threads(threads):
        pair_set = pairs if isinstance(pairs, PairSet) else PairSet.load(pairs, log=say)
        train, val = pair_set.validation_split(config.val_fraction, config.seed)
        say(f"training on {len(train)} pairs, validating on {len(val)} ({len(set(val.scenes))} scenes)")
        if config.patience and not len(val):
            say("no validation pairs: the fit runs every epoch (early stopping needs validation)")
        started = time.perf_counter()
        sensor, resolution_note = _sensor(config, train, initial, say)
        baseline_pairs = train.images if sensor is None else _through(sensor, train.unit_pairs())
        baseline = fit_linear_baseline(baseline_pairs, seed=config.seed)
        if initial is None and config.arch == LocalAffineNet.arch:
            initial = _from_baseline(config, baseline)
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
            after=sensor,
        )
        minutes = (time.perf_counter() - started) / 60
        scores = validation_psnr(network, baseline, val, sensor)
        network_gain = network_gain_db(scores)
        keep_network = network_gain is None or network_gain["best"] >= NETWORK_MIN_GAIN_DB
        if not keep_network:
            say(
                f"network dropped: its gain over the clean image is {network_gain['network']:+.2f} dB on the "
                f"validation pairs (the linear baseline's {network_gain['baseline']:+.2f} dB), less than "
                f"{NETWORK_MIN_GAIN_DB} dB; the profile holds effect stages only"
            )
        profile = CameraProfile(network if keep_network else None, name=name, description=description)
        if sensor is not None and keep_network:
            profile = profile.with_effects(sensor)
        elif sensor is not None:
            resolution_note = {
                **resolution_note,
                "kept": False,
                "reason": "the network it was trained with was dropped",
            }
        eight_bit = all(captured.dtype == torch.uint8 for _, captured in pair_set.images)
        train_pairs, val_pairs = train.unit_pairs(), val.unit_pairs()
        pairs = (train, val, train_pairs, val_pairs)
        profile, effect_notes = _effect_stages(profile, pairs, config, keep_network, say, eight_bit=eight_bit)
        texture_note = {"kept": False, "reason": f"texture={config.texture!r}" if keep_network else "no network"}
        denoise_note, response_note = dict(texture_note), dict(texture_note)
        if config.texture == "match" and keep_network:
            profile, texture_note = fit_texture(profile, train_pairs, val_pairs, say, seed=config.seed)
            profile, denoise_note = fit_denoise(profile, train_pairs, val_pairs, say, seed=config.seed)
            profile, response_note = fit_response(profile, train_pairs, val_pairs, say, seed=config.seed)
        profile.fitted = _record(pair_set, train, val, config, history, minutes, effect_notes)
        profile.fitted["resolution"] = resolution_note
        profile.fitted["texture"] = texture_note
        profile.fitted["denoise"] = denoise_note
        profile.fitted["response"] = response_note
        profile.fitted["init_from"] = init_label
        profile.fitted["network"] = _network_note(keep_network, network_gain)
        profile.fitted["trained_in"] = str(training_dtype(config.precision, torch.device(device))).split(".")[-1]
        quality = _quality(profile, scores, val, eight_bit, say) if scores is not None else {}
        record_quality(profile, quality, _warnings(quality, history, config, keep_network), say)
        return profile


def _silent(message: str) -> None:
    pass


def _effect_stages(
    profile: CameraProfile,
    pairs: tuple[PairSet, PairSet, list[ImagePair], list[ImagePair]],
    config: FitConfig,
    keep_network: bool,
    say: Log,
    *,
    eight_bit: bool,
) -> tuple[CameraProfile, dict[str, Any]]:
    """The recipe's effect stages (:func:`~camdegrade.fitting.stages.fit_effects`), after a colour stage for the shift
    between the channels where the network that held it was dropped (:mod:`camdegrade.fitting.colour_shift`, its
    evidence in the notes as ``color``, unless the recipe fits a colour stage itself)."""
    train, val, train_pairs, val_pairs = pairs
    shift_note = None
    if not keep_network and Color.name not in config.effects:
        scenes = [*train.scenes, *val.scenes]
        profile, shift_note = keep_colour_shift(profile, train_pairs, [*train_pairs, *val_pairs], scenes, say)
    profile, notes = fit_effects(profile, train_pairs, val_pairs, config.effects, say, eight_bit=eight_bit)
    return profile, notes if shift_note is None else {Color.name: shift_note, **notes}


def _warnings(quality: dict[str, Any], history: Sequence[EpochResult], config: FitConfig, kept: bool) -> list[str]:
    """What the validation scores warn about. A dropped network is not warned about (the profile does not hold it),
    unless the captures are the clean images themselves, which is the user's mistake to hear about."""
    identical = not math.isfinite(quality.get("identity_psnr_db", 0.0))
    return quality_warnings(quality) + still_rising(history, config) if kept or identical else []


def _check_arguments(pairs: Any, name: Any, description: Any) -> None:
    """What can be refused before any pair is read or any epoch trained."""
    if pairs is None:
        raise TypeError(
            "pairs must be a folder, a CSV manifest, a list of pairs or of (clean, captured) tensors, got None"
        )
    for label, text in (("name", name), ("description", description)):
        if not isinstance(text, str):
            raise TypeError(f"{label} must be a str, got {label}={text!r} ({type(text).__name__})")


def quality_warnings(quality: dict[str, Any]) -> list[str]:
    """What a fit's validation scores (:func:`_quality`'s) say is wrong: a network that does worse than passing the
    clean image through unchanged (too few epochs, too few pairs, or pairs that show no difference), or worse than
    the least-squares linear baseline (:mod:`camdegrade.fitting.baseline`: a simple answer it should beat)."""
    network, identity = quality.get("network_psnr_db"), quality.get("identity_psnr_db")
    baseline = quality.get("baseline_psnr_db")
    if network is not None and identity is not None and network < identity:
        return [
            f"the fitted network is worse than the identity on the validation pairs ({_db(network)} vs "
            f"{_db(identity)} for the clean images unchanged): fit longer (--epochs), on more pairs, or check that "
            "the captures differ from the clean images"
        ]
    if network is not None and baseline is not None and network < baseline - BASELINE_TOLERANCE_DB:
        return [
            f"the fitted network is worse than a linear colour filter fitted by least squares on the same pairs "
            f"({_db(network)} vs {_db(baseline)} on the validation pairs): fit longer (--epochs), or use "
            "--arch local_affine, which starts from that filter"
        ]
    return []


#: A last epoch that adds at least this much validation PSNR (dB) to the best before it says the fit stopped rising
#: too early: more than seed noise moves the best (about ±0.1 dB over a whole fit) spread over its last epoch.
STILL_RISING_DB = 0.05


def still_rising(history: Sequence[EpochResult], config: FitConfig) -> list[str]:
    """A warning when the fit ran out of epochs while its validation PSNR was still rising: the last epoch was the
    best and beat the best before it by :data:`STILL_RISING_DB` or more."""
    scores = [result.val_psnr for result in history if math.isfinite(result.val_psnr)]
    if len(scores) < 2 or len(history) < config.epochs or not history[-1].is_best:
        return []
    gain = scores[-1] - max(scores[:-1])
    if gain < STILL_RISING_DB:
        return []
    return [
        f"the validation PSNR was still rising at the last epoch (+{gain:.2f} dB over the best before it): the fit "
        f"may stop short; fit longer (--epochs {2 * config.epochs})"
    ]


#: A network within this much of the baseline's validation PSNR is not warned about (float and crop noise).
BASELINE_TOLERANCE_DB = 0.05

#: A fitted network is kept only when it (or the linear baseline) beats the clean image passed through unchanged by
#: at least this much validation PSNR; otherwise the profile holds its effect stages alone. On the real-noise pairs
#: of ``bench/bench_noise_gap.py`` (clean = the mean of many frames, so the camera's expected capture *is* the clean
#: image) the networks gained 0.04–0.09 dB on validation by fitting the training captures' exposure offsets, and a
#: denoiser trained on their output lost 0.07–0.18 dB on real held-out captures against the noise stage alone; a
#: camera with a lens, colour or tone effect gains whole dBs (City100: the clean image 23.8 dB, the network 30.4;
#: the half-bright camera of ``tests/test_network_drop.py``: more than 3 dB).
NETWORK_MIN_GAIN_DB = 0.2


def validation_psnr(
    network: ShiftNetwork,
    baseline: tuple[torch.Tensor, torch.Tensor],
    val: PairSet,
    sensor: Resolution | None = None,
) -> dict[str, float] | None:
    """Mean validation PSNR (dB) against the captures of the clean images unchanged (``identity``), the linear
    baseline and the trained network (both through ``sensor`` when the fit found one); ``None`` without validation
    pairs."""
    if not len(val):
        return None
    pairs = val.unit_pairs()
    network.eval()
    with torch.no_grad():
        identity = sum(psnr(clean, captured) for clean, captured in pairs) / len(pairs)
        outputs = [network(clean[None]) for clean, _ in pairs]
        if sensor is not None:
            outputs = [sensor(output) for output in outputs]
        predicted = sum(psnr(output[0], captured) for output, (_, captured) in zip(outputs, pairs)) / len(pairs)
    return {"identity": identity, "baseline": baseline_psnr(*baseline, pairs, sensor), "network": predicted}


def _sensor(
    config: FitConfig, train: PairSet, initial: ShiftNetwork | None, say: Log
) -> tuple[Resolution | None, dict[str, Any]]:
    """The sensor stage the network is trained through (``config.sensor_scale`` below 1, or found from the training
    captures with ``"auto"``; only for a ``local_affine`` network trained from the baseline: a refit continues its
    network as it was trained); and the note for ``fitted['resolution']``."""
    if config.sensor_scale == "auto":
        if config.arch != LocalAffineNet.arch or initial is not None:
            return None, {"kept": False, "reason": "auto: only a local_affine network trained from its baseline"}
        cleans, captures = [clean for clean, _ in train.images], [captured for _, captured in train.images]
        return find_sensor(cleans, captures, say, then="the network is trained through it")
    if config.sensor_scale >= 1:
        return None, {"kept": False, "scale": 1.0}
    sensor = Resolution(config.sensor_scale)  # FitConfig and fit_profile refused it with arch='paper' or init_from
    say(
        f"resolution: the network is trained through a sensor at {config.sensor_scale:.4g}x (windows every "
        f"{sensor.period} px)"
    )
    return sensor, {"kept": True, "scale": round(float(config.sensor_scale), 4), "period": sensor.period}


def _through(sensor: Resolution | None, pairs: Sequence[ImagePair]) -> list[ImagePair]:
    """``pairs`` with each clean image passed through ``sensor`` (unchanged without one)."""
    if sensor is None:
        return list(pairs)
    with torch.no_grad():
        return [(sensor(clean[None])[0], captured) for clean, captured in pairs]


def network_gain_db(scores: dict[str, float] | None) -> dict[str, float] | None:
    """The gain over the identity (dB) of the network, of the linear baseline and the better of the two, from
    :func:`validation_psnr`'s scores; ``None`` without them (nothing to judge on: the network is kept)."""
    if scores is None:
        return None
    # Captures identical to the clean images make the identity's PSNR infinite: no finite gain over it (-inf).
    gains = {key: scores[key] - scores["identity"] for key in ("network", "baseline")}
    gains = {key: -math.inf if math.isnan(gain) else gain for key, gain in gains.items()}
    return {key: round(value, 3) for key, value in {**gains, "best": max(gains.values())}.items()}


def _network_note(kept: bool, gain: dict[str, float] | None) -> dict[str, Any]:
    """``fitted['network']``: whether the network was kept, and the validation gains it was judged on."""
    note: dict[str, Any] = {"kept": kept, "min_gain_db": NETWORK_MIN_GAIN_DB}
    if gain is not None:
        note["gain_db"] = gain["network"]
        note["baseline_gain_db"] = gain["baseline"]
    return finite_or_none(note)


def _db(value: float) -> str:
    return f"{value:.2f} dB" if math.isfinite(value) else f"{value} dB"


def record_quality(profile: CameraProfile, quality: dict[str, Any], warnings: list[str], say: Log) -> None:
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


def _record(
    pair_set: PairSet,
    train: PairSet,
    val: PairSet,
    config: FitConfig,
    history: Sequence[EpochResult],
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
        "aligned": pair_set.shifts is not None,
        "recipe": config.training_dict(),
        "best_epoch": best.epoch,
        "fit_minutes": round(minutes, 2),
        "effects": effect_notes,
        "machine": f"{platform.machine()}, {torch.get_num_threads()} threads, torch {torch.__version__}",
        "camdegrade": __version__,
        "torch": versions["torch"] or str(torch.__version__),
        "torchvision": versions["torchvision"],
    }


def _from_baseline(config: FitConfig, baseline: tuple[torch.Tensor, torch.Tensor]) -> ShiftNetwork:
    """A fresh :class:`LocalAffineNet` (seeded) whose full-resolution filter is the least-squares baseline: the fit
    starts at the simple answer and can only keep or improve on it."""
    network = new_network(config)
    with torch.no_grad():
        network.linear.weight.copy_(baseline[0])
        network.linear.bias.copy_(baseline[1])
    return network


def _initial_network(
    init_from: CameraProfile | str | os.PathLike[str] | None, config: FitConfig
) -> tuple[ShiftNetwork | None, str | None]:
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
    if profile.network.width != config.width:
        raise ValueError(
            f"init_from: profile {label!r} has a network of width {profile.network.width}; this fit's width is "
            f"{config.width}, so it cannot start from it (pass width={profile.network.width})"
        )
    return profile.network, label


def _unreadable(pair_set: PairSet) -> list[dict[str, str]]:
    """The files skipped because they could not be read (truncated, too large, ...) or because a manifest names a
    file that does not exist: ``{"path", "reason"}`` (the CLI lists them and exits with status 1)."""
    skipped = pair_set.report.skipped if pair_set.report is not None else []
    failed = (UNREADABLE, MISSING)
    return [{"path": str(path), "reason": reason} for path, reason in skipped if reason.startswith(failed)]


def _quality(
    profile: CameraProfile, scores: dict[str, float], val: PairSet, eight_bit: bool, say: Log
) -> dict[str, Any]:
    """Validation PSNR of identity, the least-squares linear baseline (:mod:`camdegrade.fitting.baseline`), the
    trained network's mean (``scores``, :func:`validation_psnr`; also when the profile dropped the network) and the
    full (stochastic, seeded) profile against the captures, and how close the sampled profile looks to the captures
    (``fidelity``, :func:`_fidelity`)."""
    sampled = simulate(profile, val.cleans(), seed=0, stream="quality")
    full = [psnr(sim, captured) for (_, captured), sim in zip(val.unit_pairs(), sampled, strict=True)]
    return {
        "validation_pairs": len(val),
        "identity_psnr_db": round(scores["identity"], 3),
        "baseline_psnr_db": round(scores["baseline"], 3),
        "network_psnr_db": round(scores["network"], 3),
        "profile_psnr_db": round(sum(full) / len(full), 3),
        "fidelity": _fidelity(as_stored(sampled, eight_bit), val, say),
    }


#: The critic at the end of a fit trains on half the validation scenes and is scored on the other half; with fewer
#: than this many scenes one side would hold a single scene, whose bootstrap interval says nothing.
MIN_CRITIC_SCENES = 4
#: Critic seeds at the end of a fit, each training one critic per half of the validation scenes (4 critics in all):
#: single critics of the City100 built-in's image-only test range from 0.70 to 0.83 (docs/results.md). On City100's 8
#: validation frames the 8 critics of both modes take 21 s, one per mode took 4 s (AMD EPYC Zen 3, 2 threads).
FIT_CRITIC_SEEDS = 2


def _fidelity(sampled: Sequence[torch.Tensor], val: PairSet, say: Log) -> dict[str, Any]:
    """How close the sampled profile (rounded as the captures are stored) looks to the validation captures: grid
    ratio, band log2 power ratios, flat noise and banding ratios (:mod:`camdegrade.measures.fidelity`; ``None``
    where not measurable), and the accuracy of a critic that tells them apart with the clean source beside the
    image (``critic_paired``) and from the image alone (``critic_image_only``, what a model trained on the
    simulation sees): :func:`~camdegrade.measures.critic.repeated_critic_test` with :data:`FIT_CRITIC_SEEDS`
    seeds, ``None`` with fewer than :data:`MIN_CRITIC_SCENES` validation scenes."""
    cleans, captures = zip(*val.unit_pairs(), strict=True)
    report = measure_fidelity(list(sampled), list(captures), list(cleans)).to_dict(digits=3)
    report.pop("psnr")  # profile_psnr_db already
    scenes = len(set(val.scenes))
    for key, image_only in (("critic_paired", False), ("critic_image_only", True)):
        report[key] = None
        if scenes < MIN_CRITIC_SCENES:
            continue
        pairs = (list(cleans), list(captures), list(sampled))
        result = repeated_critic_test(pairs, val.scenes, FIT_CRITIC_SEEDS, image_only=image_only)
        report[key] = result.to_dict()
        say(f"fidelity: {result.describe()} ({'image only' if image_only else 'paired'}, {result.seconds:.1f} s)")
    if scenes < MIN_CRITIC_SCENES:
        say(f"fidelity: no critic ({scenes} validation scene(s); it needs {MIN_CRITIC_SCENES}, half to train it)")
    return report


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
