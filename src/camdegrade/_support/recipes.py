"""The fitting recipes' values and fields, in one place and without torch.

A recipe is its training values (one :class:`~camdegrade.fitting.FitConfig` field each), the share of scenes that
validates, and one ordered tuple of fit steps with their options (``steps``: ``(name, options)`` pairs; the classes
are in :mod:`camdegrade.fitting.steps`). :data:`FIELDS` is the one table of what can be set: each entry is a
``FitConfig`` field, an option of a step (``step="effects.names"``) or a choice that says whether some steps run
(``toggles``). The command line makes its recipe options from it (``camdegrade fit``/``distill``: type, help, the
default shown), ``FitConfig`` checks every value by it (:func:`check_value`), and ``FitConfig.replace`` maps a step's
field onto its step, so a new recipe field cannot be left out of any of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from camdegrade._support.checks import check_seed

#: camdegrade's default recipe: many small steps on small windows (batches of 8 windows of 64², 32 per pair and
#: epoch: the pixels of 8 windows of 128², in four times the steps), Adam on a cosine schedule over 10 epochs,
#: stopping early once the validation PSNR stops rising (``patience`` epochs without 0.01 dB of progress). Chosen by
#: the time to a good network (docs/results.md, *The recipes: time to a good network*).
FAST: dict[str, Any] = {
    "epochs": 10,
    "crop": 64,
    "batch_size": 8,
    "lr": 0.003,
    "lr_halving_epochs": 30,
    "crops_per_pair": 32,
    "seed": 0,
    "schedule": "cosine",
    "patience": 4,
    "precision": "auto",
    "width": 64,
    "arch": "local_affine",
    "upsample": "bilinear",
    "curves": "channel",
    "val_fraction": 0.15,
    "steps": (
        ("resolution", {"scale": "auto"}),
        ("effects", {"names": ("noise", "vignetting", "cfa", "jpeg")}),
        ("resampler", {}),
        ("texture", {}),
        ("denoise", {}),
        ("response", {}),
        ("mosaic", {}),
        ("jitter", {}),
    ),
}
#: The paper's schedule (Hegde et al.): 100 epochs, Adam at lr 0.01 halved every 30 epochs, batch 32, no early stop;
#: 8 windows of 128² per pair and epoch.
PAPER: dict[str, Any] = {
    **FAST,
    "epochs": 100,
    "crop": 128,
    "batch_size": 32,
    "lr": 0.01,
    "crops_per_pair": 8,
    "schedule": "step",
    "patience": 0,
    "arch": "paper",
    "curves": "none",
    "steps": (("resolution", {"scale": 1.0}), ("effects", {"names": ("noise", "vignetting")})),
}
RECIPES: dict[str, dict[str, Any]] = {"fast": FAST, "paper": PAPER}


@dataclass(frozen=True)
class RecipeField:
    """One recipe value as the command line offers it: ``kind`` names the rule it must meet (``count``: an integer
    >= 1, ``count0``: >= 0, ``number``: > 0, ``fraction``: in [0, 1), ``seed``, ``choice``: one of ``choices``,
    ``names``: any number of names, none for the empty tuple, ``sensor``: ``auto`` or a number from
    :data:`MIN_SENSOR_SCALE` to 1). Where it lives: a ``FitConfig`` field of its name; or ``step``, an option of a fit
    step (``"effects.names"``); or ``toggles``, steps that run where its value is its first choice and not where it
    is ``"none"``. ``note`` finishes the message that refuses a value (``count0``: what 0 means)."""

    name: str
    kind: str
    help: str
    choices: tuple[str, ...] = ()
    step: str = ""
    toggles: tuple[str, ...] = ()
    note: str = ""

    @property
    def option(self) -> str:
        return "--" + self.name.replace("_", "-")

    @property
    def plain(self) -> bool:
        """Whether it is a field of ``FitConfig`` itself (not a step's)."""
        return not (self.step or self.toggles)


SCHEDULES: tuple[str, ...] = ("step", "cosine")
#: The network architectures (``camdegrade.network.ARCHITECTURES``, which imports torch; a test keeps them equal).
ARCHS: tuple[str, ...] = ("paper", "local_affine")
#: How ``local_affine`` brings its colour field to full resolution (``camdegrade.network.FIELD_UPSAMPLING``).
UPSAMPLINGS: tuple[str, ...] = ("bilinear", "smooth")
#: ``local_affine``'s pointwise curves (``camdegrade.network.LocalAffineNet``'s ``curves``): ``channel``, one learned
#: curve per channel before its filter and one after its colour transform (a lens blurs linear light and the ISP's
#: tone curve follows it); ``none``, the network without them (what profiles written before this option hold).
CURVES: tuple[str, ...] = ("none", "channel")
TRAIN_PRECISIONS: tuple[str, ...] = ("auto", "float32", "bfloat16")
#: ``match``: after the effect stages, a blur and a sharpening that match the profile's band power to the captures'
#: (:mod:`camdegrade.fitting.steps.texture`), then a noise reduction that matches its faint detail to theirs
#: (:mod:`camdegrade.fitting.steps.denoise`), each where the validation pairs confirm it; ``none``: no such stages.
TEXTURES: tuple[str, ...] = ("match", "none")
#: ``critic``: a learned texture stage last, trained against a critic (:mod:`camdegrade.fitting.two_sample`), kept
#: where held-out data confirm it; ``none``: not (every recipe's default; ``fit --unpaired`` fits it by default).
LEARNED_TEXTURES: tuple[str, ...] = ("critic", "none")
#: Whether a fit reads a random displacement of the captures' detail (:mod:`camdegrade.fitting.evidence.jitter_step`).
JITTERS: tuple[str, ...] = ("match", "none")
#: The smallest sensor scale a recipe accepts (``camdegrade.effects.Resolution.MIN_SCALE``; a test keeps them equal).
MIN_SENSOR_SCALE = 0.125

FIELDS: tuple[RecipeField, ...] = (
    RecipeField("epochs", "count", "most epochs"),
    RecipeField("crop", "count", "training crop size, a multiple of 4"),
    RecipeField("batch_size", "count", "crops per step"),
    RecipeField("lr", "number", "Adam learning rate at the start"),
    RecipeField("lr_halving_epochs", "count", "with the step schedule: halve the learning rate every N epochs"),
    RecipeField("crops_per_pair", "count", "random crops per pair per epoch"),
    RecipeField("seed", "seed", "initialisation, crops and the validation split"),
    RecipeField(
        "schedule", "choice", "how the learning rate moves: halved in steps, or along a half cosine", SCHEDULES
    ),
    RecipeField(
        "patience",
        "count0",
        "stop after N epochs without a better validation PSNR (by 0.01 dB), 0 never stops",
        note="0: no early stopping",
    ),
    RecipeField(
        "precision",
        "choice",
        "arithmetic of the training passes; auto: bfloat16 where the device computes it natively",
        TRAIN_PRECISIONS,
    ),
    RecipeField("width", "count", "network width (32 runs about 4x cheaper, see 'camdegrade distill')"),
    RecipeField(
        "arch",
        "choice",
        "network: local_affine (no 4-pixel grid, starts from a least-squares linear baseline) or the paper's",
        ARCHS,
    ),
    RecipeField(
        "upsample",
        "choice",
        "local_affine's colour field: bilinear, or smooth (its slope does not change every 4 pixels)",
        UPSAMPLINGS,
    ),
    RecipeField(
        "curves",
        "choice",
        "local_affine's pointwise curves: channel (one per channel before its filter and after its colour "
        "transform, as a lens blurs linear light before the tone curve) or none",
        CURVES,
    ),
    RecipeField("val_fraction", "fraction", "share of scenes held out to choose the best epoch"),
    RecipeField(
        "effects",
        "names",
        "effect stages fitted after the network, from the registry (none: network only)",
        step="effects.names",
    ),
    RecipeField(
        "texture",
        "choice",
        "match: add a blur, a sharpening and a noise reduction that match the captures' band power and faint "
        "detail, where validation confirms it",
        TEXTURES,
        toggles=("texture", "denoise", "response"),
    ),
    RecipeField(
        "sensor_scale",
        "sensor",
        "a camera that upscales: its sensor's resolution relative to its output (0.5: every other pixel "
        "sampled), the network trained through it; auto: found from the captures (1/2, 1/3, 1/4); 1: none",
        step="resolution.scale",
    ),
    RecipeField(
        "learned_texture",
        "choice",
        "critic: last, a small network trained against a critic (and L2 on the pairs) for the texture no stage "
        "names, kept where held-out data say a fresh critic tells it less easily (with --unpaired: the default, "
        "where each half of the sets holds enough patches and the halves say so); minutes more",
        LEARNED_TEXTURES,
        toggles=("learned_texture",),
    ),
    RecipeField(
        "jitter",
        "choice",
        "match: last, a random sub-pixel displacement where the captures' detail is less coherent with the clean "
        "image than the profile's by what a displacement explains, kept where validation confirms it",
        JITTERS,
        toggles=("jitter",),
    ),
)
FIELD: dict[str, RecipeField] = {field.name: field for field in FIELDS}

#: The values of the network's training (recorded as a profile's ``fitted['recipe']`` and in a checkpoint); the
#: other fields say how the pairs are split and which steps follow.
TRAINING_FIELDS: tuple[str, ...] = tuple(field.name for field in FIELDS if field.plain and field.name != "val_fraction")
#: The effect stages a recipe fits after the network unless told otherwise.
DEFAULT_EFFECTS: tuple[str, ...] = dict(FAST["steps"])["effects"]["names"]


def field_value(field: RecipeField, values: dict[str, Any], steps: list[tuple[str, dict[str, Any]]]) -> Any:
    """``field``'s value in a recipe of plain ``values`` and ``steps`` (``(name, options)`` pairs): a step option
    (``None`` where that step is not in the recipe), or a toggle's first choice where all its steps are in the recipe
    and ``"none"`` where none is (``None`` for some)."""
    if field.plain:
        return values[field.name]
    present = dict(steps)
    if field.step:
        name, option = field.step.split(".")
        return present[name].get(option) if name in present else None
    found = [name in present for name in field.toggles]
    return field.choices[0] if all(found) else "none" if not any(found) else None


def recipe_default(key: str) -> str:
    """``key``'s value in each recipe, for help text: ``"15; paper: 100"``, or one value where they agree."""
    fast, paper = (field_value(FIELD[key], recipe, list(recipe["steps"])) for recipe in (FAST, PAPER))
    shown = (" ".join(fast) or "none") if isinstance(fast, tuple) else f"{fast}"
    return shown if fast == paper else f"{shown}; paper: {paper}"


def check_value(field: RecipeField, value: Any) -> None:
    """Refuse a value of ``field`` that breaks its kind's rule, naming the field and the value (``names`` are checked
    by the step they belong to, against the effect registry)."""
    name = field.name
    if field.kind in ("count", "count0"):
        low = 1 if field.kind == "count" else 0
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            rule = "a positive integer" if low else f"an integer >= 0 ({field.note})"
            raise ValueError(f"{name} must be {rule}, got {name}={value!r}")
    elif field.kind == "number":
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive number, got {name}={value!r}")
    elif field.kind == "fraction":
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value < 1.0:
            raise ValueError(f"{name} must be in [0, 1), got {name}={value!r}")
    elif field.kind == "choice":
        if value not in field.choices:
            raise ValueError(f"{name} must be one of {field.choices}, got {name}={value!r}")
    elif field.kind == "seed":
        check_seed(value, name)
    elif field.kind == "sensor":
        number = not isinstance(value, bool) and isinstance(value, (int, float))
        if value != "auto" and not (number and MIN_SENSOR_SCALE <= value <= 1):
            raise ValueError(f"{name} must be 'auto' or a number from {MIN_SENSOR_SCALE} to 1, got {name}={value!r}")
