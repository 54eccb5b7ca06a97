"""How a chain of effect stages runs at inference: every run of adjacent linear shift-invariant stages of one encoding
composed into one filter (:mod:`camdegrade.effects.linear`), every other stage as itself.

The plan is built from the stages when a chain first runs and rebuilt whenever one of their tensors or settings
changes (as the network's CPU plan is); it is never stored: a profile file keeps its stages as fitted.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from torch import Tensor

from camdegrade._support.fingerprint import module_tensors, tensors_fingerprint
from camdegrade.effects.base import Effect, Encoding
from camdegrade.effects.linear import LinearFilter
from camdegrade.functional.isp.color import linear_to_srgb_, srgb_to_linear_

__all__ = [
    "PLANS_KEPT",
    "ChainPlan",
    "FilterRun",
    "chain_plan",
    "encoded",
]


@dataclass
class FilterRun:
    """Adjacent stages ``indices`` of a chain as one composed ``filter``. Where a separable kernel would read past
    the frame's far border (an image no larger than the composed radius), the stages run one by one instead, as
    their own forwards handle such images."""

    indices: tuple[int, ...]
    filter: LinearFilter
    caches: tuple[dict, dict] = field(default_factory=lambda: ({}, {}))

    def run_(self, effects: Sequence[Effect], params: Sequence[Mapping[str, Tensor]], image: Tensor) -> Tensor:
        if self.filter.radius() >= min(image.shape[-2:]):
            for index in self.indices:
                image = effects[index].forward_encoded(image, params[index])
            return image
        return self.filter.run_(image, self.caches)


@dataclass
class ChainPlan:
    """The steps of a chain: an index of a stage that runs as itself, or a :class:`FilterRun`."""

    steps: list[int | FilterRun]

    @classmethod
    def of(cls, effects: Sequence[Effect]) -> ChainPlan:
        """Adjacent stages that state a :meth:`~Effect.linear_filter` composed while
        :meth:`~camdegrade.effects.linear.LinearFilter.composes_with` holds (one encoding; a run ends at a stage that
        clamps, a clamp not being linear, and after a kernel that would not keep a mirrored border mirrored); runs
        that are the identity left out."""
        steps: list[int | FilterRun] = []
        for index, effect in enumerate(effects):
            stated = effect.linear_filter()
            last = steps[-1] if steps else None
            if stated is None:
                steps.append(index)
            elif isinstance(last, FilterRun) and last.filter.composes_with(stated):
                steps[-1] = FilterRun((*last.indices, index), last.filter.then(stated))
            else:
                steps.append(FilterRun((index,), stated))
        return cls([step for step in steps if not (isinstance(step, FilterRun) and step.filter.is_identity)])

    def run_(self, effects: Sequence[Effect], params: Sequence[Mapping[str, Tensor]], image: Tensor) -> Tensor:
        """``image`` (sRGB floats, owned by the caller: it may be overwritten) through the chain; sRGB out."""
        encoding: Encoding = "srgb"
        for step in self.steps:
            if isinstance(step, FilterRun):
                image = encoded(image, encoding, step.filter.encoding)
                image, encoding = step.run_(effects, params, image), step.filter.encoding
            else:
                wanted, produced = effects[step].encodings()
                image = effects[step].forward_encoded(encoded(image, encoding, wanted), params[step])
                encoding = produced
        return encoded(image, encoding, "srgb")


def encoded(image: Tensor, current: Encoding, wanted: Encoding) -> Tensor:
    """``image`` in ``current`` encoding converted in place to ``wanted``."""
    if current == wanted:
        return image
    return srgb_to_linear_(image) if wanted == "linear" else linear_to_srgb_(image)


#: Plans kept, the most recently used last: a profile's chain, and the few chains a fit or a diagnosis simulates.
PLANS_KEPT = 16
_PLANS: OrderedDict[tuple[int, ...], tuple[tuple, Sequence[Effect], ChainPlan]] = OrderedDict()
_PLANS_LOCK = threading.Lock()


def chain_plan(effects: Sequence[Effect]) -> ChainPlan:
    """The plan of ``effects``, cached: rebuilt whenever a stage's tensors (values, in place or swapped) or settings
    change. The cache holds the stages it planned, so their identities stay theirs while it does."""
    identities = tuple(id(effect) for effect in effects)
    state = (
        tensors_fingerprint(tensor for effect in effects for tensor in module_tensors(effect)),
        tuple(repr(effect.config()) for effect in effects),
    )
    with _PLANS_LOCK:
        cached = _PLANS.get(identities)
        if cached is not None and cached[0] == state:
            _PLANS.move_to_end(identities)
            return cached[2]
    plan = ChainPlan.of(effects)
    with _PLANS_LOCK:
        _PLANS[identities] = (state, tuple(effects), plan)
        if len(_PLANS) > PLANS_KEPT:
            _PLANS.popitem(last=False)
    return plan
