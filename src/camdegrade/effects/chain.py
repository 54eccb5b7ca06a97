"""Running a sequence of effect stages, decoding sRGB to linear light only where the encoding changes."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence

from torch import Tensor

from camdegrade.effects.base import STAGES, Effect
from camdegrade.effects.plan import chain_plan

__all__ = ["apply_effects", "chain_moved_points", "chain_source_points", "check_chain", "check_params", "moves_pixels"]


def check_chain(effects: Sequence[Effect], *, ordered: bool = False) -> None:
    """Raise unless every item of ``effects`` is an :class:`Effect` (a ``TypeError`` naming the first that is not)
    and, with ``ordered``, they come in physical stage order (a ``ValueError``)."""
    for index, effect in enumerate(effects):
        if not isinstance(effect, Effect):
            raise TypeError(f"effects[{index}] must be a camdegrade Effect, got {type(effect).__name__}")
    ranks = [STAGES.index(effect.stage) for effect in effects]
    if ordered and ranks != sorted(ranks):
        order = ", ".join(f"{effect.name} ({effect.stage})" for effect in effects)
        raise ValueError(f"effects must be in physical stage order {' → '.join(STAGES)}, got {order}")


def check_params(effects: Sequence[Effect], params: Sequence[Mapping[str, Tensor]]) -> None:
    """Raise a ``ValueError`` unless ``params`` holds one entry per stage."""
    if len(params) != len(effects):
        raise ValueError(f"params must hold one entry per effect ({len(effects)}), got {len(params)}")


def apply_effects(
    effects: Sequence[Effect], params: Sequence[Mapping[str, Tensor]], image: Tensor, *, overwrite: bool = False
) -> Tensor:
    """``image`` (sRGB floats) through every stage in order, as stage-by-stage ``effect(image, params)`` would be.

    Without autograd, the chain's plan runs (:func:`camdegrade.effects.plan.chain_plan`) on one working tensor
    (``image`` itself when ``overwrite``, else a copy): adjacent linear shift-invariant stages as one composed
    filter, the others through :meth:`Effect.forward_encoded`, in place where they can, a run of linear-light
    stages (blur, vignetting, noise, colour, …) sharing a single decode and encode. With a graph to build, each
    stage's ``forward`` runs in turn (:func:`apply_stages`).
    """
    check_params(effects, params)
    if image.requires_grad:
        return apply_stages(effects, params, image)
    return chain_plan(effects).run_(effects, params, image if overwrite else image.clone())


def apply_stages(effects: Sequence[Effect], params: Sequence[Mapping[str, Tensor]], image: Tensor) -> Tensor:
    """``image`` through each stage's ``forward`` in turn: the reference the plan is held to (and the path that
    builds a graph)."""
    for effect, effect_params in zip(effects, params, strict=True):
        image = effect(image, effect_params)
    return image


def moves_pixels(effects: Sequence[Effect]) -> bool:
    """Whether any stage of ``effects`` moves image content (so targets must move with it)."""
    return any(effect.moves_pixels for effect in effects)


def chain_source_points(
    effects: Sequence[Effect], params: Sequence[Mapping[str, Tensor]], x: Tensor, y: Tensor, size: tuple[int, int]
) -> tuple[Tensor, Tensor]:
    """Where in the chain's input the output positions ``(x, y)`` read from: each moving stage's
    :meth:`~Effect.source_points`, last stage first (coordinates as there)."""
    stages = reversed(list(zip(effects, params, strict=True)))
    return _map_points(stages, "source_points", x, y, size)


def chain_moved_points(
    effects: Sequence[Effect], params: Sequence[Mapping[str, Tensor]], x: Tensor, y: Tensor, size: tuple[int, int]
) -> tuple[Tensor, Tensor]:
    """Where the chain puts its input positions ``(x, y)``: each moving stage's :meth:`~Effect.moved_points`, in
    chain order (the inverse of :func:`chain_source_points`)."""
    return _map_points(zip(effects, params, strict=True), "moved_points", x, y, size)


def _map_points(
    stages: Iterable[tuple[Effect, Mapping[str, Tensor]]], method: str, x: Tensor, y: Tensor, size: tuple[int, int]
) -> tuple[Tensor, Tensor]:
    """``(x, y)`` through the point map ``method`` of each moving stage of ``stages``, in the order given."""
    for effect, effect_params in stages:
        if effect.moves_pixels:
            x, y = getattr(effect, method)(x, y, size, effect_params)
    return x, y
