"""A fitting recipe (:class:`FitConfig`): the network's training values, the share of scenes that validates, and the
fit's steps in order, each with its options (:mod:`camdegrade.fitting.steps`). Every value is checked by the one
recipe table (:data:`camdegrade._support.recipes.FIELDS`), from which the command line's options are made too."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, fields
from typing import Any

from camdegrade._support.recipes import (
    FAST,
    FIELD,
    FIELDS,
    RECIPES,
    TRAINING_FIELDS,
    RecipeField,
    check_value,
    field_value,
)
from camdegrade.fitting.steps import STEPS, FitStep
from camdegrade.network import MAX_WIDTH, SIZE_MULTIPLE

__all__ = ["FitConfig", "resolve_recipe"]

#: A step as a recipe may name it: a step object, a registered name (its options' defaults), or ``(name, options)``.
StepSpec = FitStep | str | tuple[str, Mapping[str, Any]]


@dataclass(frozen=True)
class FitConfig:
    """A fitting recipe: L2 loss and Adam on random ``crop``×``crop`` windows of the full-resolution pairs (instead of
    the paper's squashed resizes); an epoch draws ``crops_per_pair`` windows from every training pair; a share
    ``val_fraction`` of the scenes validates; then the fit runs its ``steps`` in order.

    The defaults are camdegrade's fast recipe (``RECIPES["fast"]``, :mod:`camdegrade._support.recipes`): batches of 8,
    Adam on a cosine schedule, stopping early once the validation PSNR has not risen for ``patience`` epochs.
    ``FitConfig.recipe("paper")`` is the paper's: 100 epochs, Adam at lr 0.01 halved every 30 epochs, batch 32,
    no early stopping. Either trains in bfloat16 where the device computes it natively (``precision="auto"``).
    Change values with :meth:`replace`, a step's options by their field's name as well:
    ``FitConfig.recipe("fast").replace(epochs=3, effects=(), texture="none")``.

    Args:
        patience: stop after this many epochs without a better validation PSNR (by at least 0.01 dB); 0 never
            stops early. The best epoch's weights are returned either way.
        schedule: one of :data:`~camdegrade._support.recipes.SCHEDULES`: ``"step"`` halves the learning rate every
            ``lr_halving_epochs`` epochs (the paper's); ``"cosine"`` lowers it from ``lr`` to 0 along a half cosine
            over ``epochs``, one step per epoch.
        precision: one of :data:`~camdegrade._support.recipes.TRAIN_PRECISIONS`: ``"bfloat16"`` autocasts the
        convolutions
            (float32 weights, optimizer and loss); ``"auto"`` does so where the device computes bfloat16 natively.
        width: the network's width (the paper's 64).
        arch: the network (:data:`~camdegrade.network.ARCHITECTURES`): ``"local_affine"`` (the fast recipe's; no
            4-pixel grid) or ``"paper"`` (the paper recipe's, :class:`~camdegrade.network.DomainShiftNet`).
        upsample: how ``local_affine`` brings its colour field to full resolution, one of
            :data:`~camdegrade.network.FIELD_UPSAMPLING` (the paper network ignores it).
        curves: ``local_affine``'s pointwise curves, one of :data:`~camdegrade._support.recipes.CURVES`: ``"channel"``
        (the
            fast recipe's) or ``"none"`` (the paper recipe's; the paper network ignores it).
        val_fraction: share of *scenes* held out for choosing the best epoch and judging the steps
            (``fit_profile``; ``distill_profile`` holds out that share of its images, at least one).
        steps: what ``fit_profile`` does besides training the network, in order (:data:`~camdegrade.fitting.steps.
            STEPS`; ``distill_profile`` copies its teacher's stages instead): step objects, registered names or
            ``(name, options)``. The fast recipe's: ``resolution`` (``scale="auto"``: the sensor resolution found in
            the training captures, the network trained through it; a number below 1: that scale), then after the
            network ``effects`` (``names``: the effect stages, each kept where the validation pairs show it),
            ``texture``, ``denoise`` and ``response`` (what least squares smooths away, matched to the captures'
            spectrum and faint detail). The paper recipe's: ``resolution`` at scale 1 (none) and ``effects``.
            The command line's ``--sensor-scale``, ``--effects`` and ``--texture`` set them (``replace`` takes
            the same names).
    """

    epochs: int = FAST["epochs"]
    crop: int = FAST["crop"]
    batch_size: int = FAST["batch_size"]
    lr: float = FAST["lr"]
    lr_halving_epochs: int = FAST["lr_halving_epochs"]
    crops_per_pair: int = FAST["crops_per_pair"]
    seed: int = FAST["seed"]
    schedule: str = FAST["schedule"]
    patience: int = FAST["patience"]
    precision: str = FAST["precision"]
    width: int = FAST["width"]
    arch: str = FAST["arch"]
    upsample: str = FAST["upsample"]
    curves: str = FAST["curves"]
    val_fraction: float = FAST["val_fraction"]
    steps: tuple[FitStep, ...] = FAST["steps"]

    def __post_init__(self) -> None:
        object.__setattr__(self, "steps", build_steps(self.steps))
        for field in FIELDS:
            value = self.option(field.name)
            if field.plain or value is not None:  # the option of a step the recipe leaves out is not checked
                check_value(field, value)
        if self.width > MAX_WIDTH:
            raise ValueError(f"width must be at most {MAX_WIDTH}, got width={self.width}")
        if self.crop % SIZE_MULTIPLE:
            raise ValueError(f"crop must be a multiple of {SIZE_MULTIPLE}, got crop={self.crop}")
        for step in self.steps:
            step.check(self)
        first = [step.before_network for step in self.steps]
        if first != sorted(first, reverse=True):
            before = [step.name for step in self.steps if step.before_network]
            raise ValueError(f"steps: {before} come before the network (it is trained through them): put them first")

    @classmethod
    def recipe(cls, name: str = "fast", **overrides: Any) -> FitConfig:
        """The named recipe of :data:`~camdegrade._support.recipes.RECIPES`, with ``overrides`` (as :meth:`replace`)."""
        if name not in RECIPES:
            raise ValueError(f"recipe must be one of {tuple(RECIPES)}, got recipe={name!r}")
        return cls(**RECIPES[name]).replace(**overrides)

    def replace(self, **changes: Any) -> FitConfig:
        """This recipe with ``changes`` (``None`` values keep this recipe's), checked like a new one: any field of
        the recipe table (:data:`~camdegrade._support.recipes.FIELDS`) by its name, a step's option too
        (``effects=("noise",)``, ``sensor_scale=0.5``, ``texture="none"``), and ``steps`` whole."""
        changes = {key: value for key, value in changes.items() if value is not None}
        unknown = sorted(set(changes) - set(FIELD) - {"steps"})
        if unknown:
            raise TypeError(f"FitConfig has no field(s) {unknown}; its fields: {[*FIELD, 'steps']}")
        steps = build_steps(changes.pop("steps", self.steps))
        for name in [name for name in changes if not FIELD[name].plain]:
            check_value(FIELD[name], changes[name])
            steps = _with_option(steps, FIELD[name], changes.pop(name))
        return dataclasses.replace(self, **changes, steps=steps)

    def option(self, name: str) -> Any:
        """The value of the recipe table's field ``name``: a field of this recipe, an option of one of its steps
        (``None`` where the recipe leaves that step out), or a toggle (``"match"`` where the recipe runs every
        step it toggles, ``"none"`` where it runs none of them)."""
        plain = {field.name: getattr(self, field.name) for field in FIELDS if field.plain}
        return field_value(FIELD[name], plain, [(step.name, step.options()) for step in self.steps])

    def steps_with(self, network: FitStep) -> tuple[FitStep, ...]:
        """The recipe's steps with the ``network`` step in its place: after the steps it is trained through."""
        before = [step for step in self.steps if step.before_network]
        return (*before, network, *self.steps[len(before) :])

    def left_out(self) -> dict[str, str]:
        """The registered steps this recipe leaves out by a toggle of the table, each with why
        (``{"texture": "texture='none'"}``)."""
        return {
            name: f"{field.name}={'none'!r}"
            for field in FIELDS
            if field.toggles and self.option(field.name) == "none"
            for name in field.toggles
        }

    def as_dict(self) -> dict[str, Any]:
        """Every field's value (``FitConfig(**config.as_dict()) == config``)."""
        return {field.name: getattr(self, field.name) for field in fields(self)}

    def training_dict(self) -> dict[str, Any]:
        """The network's training values (:data:`~camdegrade._support.recipes.TRAINING_FIELDS`): what a profile records
        as ``fitted['recipe']`` and a checkpoint must match to be resumed."""
        return {name: getattr(self, name) for name in TRAINING_FIELDS}


def resolve_recipe(recipe: str | FitConfig) -> FitConfig:
    """``recipe``: a name of ``RECIPES`` or a :class:`FitConfig`."""
    if isinstance(recipe, FitConfig):
        return recipe
    if not isinstance(recipe, str):
        raise TypeError(f"recipe must be a recipe name {tuple(RECIPES)} or a FitConfig, got {type(recipe).__name__}")
    return FitConfig.recipe(recipe)


def build_steps(specs: Iterable[StepSpec]) -> tuple[FitStep, ...]:
    """The step objects ``specs`` name (:data:`StepSpec`), each step once."""
    if isinstance(specs, (str, FitStep)):
        specs = [specs]
    steps = []
    for spec in specs:
        if isinstance(spec, FitStep):
            steps.append(spec)
            continue
        name, options = (spec, {}) if isinstance(spec, str) else spec
        if name not in STEPS:
            raise ValueError(f"steps: no fit step is named {name!r}; the steps: {list(STEPS)}")
        steps.append(STEPS[name](**options))
    names = [step.name for step in steps]
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:
        raise ValueError(f"steps: each step runs once, got {twice} more than once")
    return tuple(steps)


def _with_option(steps: tuple[FitStep, ...], field: RecipeField, value: Any) -> tuple[FitStep, ...]:
    """``steps`` with a step field's ``value``: the option set on its step (added where the recipe left it out), or
    a toggle's steps added (its first choice) or left out (``"none"``)."""
    if field.step:
        name, option = field.step.split(".")
        if any(step.name == name for step in steps):
            return tuple(dataclasses.replace(step, **{option: value}) if step.name == name else step for step in steps)
        return _inserted(steps, STEPS[name](**{option: value}))
    if value == "none":
        return tuple(step for step in steps if step.name not in field.toggles)
    for name in field.toggles:
        if all(step.name != name for step in steps):
            steps = _inserted(steps, STEPS[name]())
    return steps


def _inserted(steps: tuple[FitStep, ...], step: FitStep) -> tuple[FitStep, ...]:
    """``steps`` with ``step`` after every step that comes before it in the registry's order."""
    order = {name: rank for rank, name in enumerate(STEPS)}  # a step of no registered name comes first
    earlier = [i + 1 for i, other in enumerate(steps) if order.get(other.name, -1) < order[step.name]]
    position = max(earlier, default=0)
    return (*steps[:position], step, *steps[position:])
