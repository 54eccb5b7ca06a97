"""Mixing policies: which items of a dataset are returned clean, degraded, or both.

A policy is a small, picklable object with no state of its own. Given a source item's index in the wrapped dataset,
the epoch and the seed it answers deterministically, so the answer is the same in every DataLoader worker and on
every rank. A policy may repeat each source item (``copies``): :class:`Union` returns every item twice.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import ClassVar

from camdegrade._support.checks import check_int, check_probability
from camdegrade.data._keys import item_uniform

__all__ = [
    "Alternate",
    "Bernoulli",
    "Decision",
    "MixPolicy",
    "PairedViews",
    "Ratio",
    "Schedule",
    "Union",
    "resolve_policy",
]

#: What :meth:`MixPolicy.decide` returns: one flag (return that view), or a tuple of flags (return a tuple of views).
Decision = bool | tuple[bool, ...]


class MixPolicy:
    """Base class: decides, for copy ``copy`` of source item ``index`` in ``epoch``, whether it is degraded.

    The wrapped dataset has ``copies * len(dataset)`` items; wrapped index ``j`` is copy ``j % copies`` of source
    item ``j // copies``, so the copies of one item sit next to each other.
    """

    #: How many times each source item appears in the wrapped dataset.
    copies: ClassVar[int] = 1

    def decide(self, index: int, copy: int, epoch: int, seed: int) -> Decision:
        raise NotImplementedError

    def __repr__(self) -> str:
        fields = ", ".join(f"{key}={value!r}" for key, value in vars(self).items())
        return f"{type(self).__name__}({fields})"

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and vars(other) == vars(self)

    def __hash__(self) -> int:
        return hash((type(self).__name__, *sorted(vars(self).items())))


class Union(MixPolicy):
    """The paper's recipe: every item appears once clean and once degraded, so the dataset doubles in length.

    Wrapped index ``2 * i`` is item ``i`` clean, ``2 * i + 1`` is item ``i`` degraded, in every epoch; exactly half
    the items are degraded. Shuffle in the DataLoader to separate the two views of an item.
    """

    copies: ClassVar[int] = 2

    def decide(self, index: int, copy: int, epoch: int, seed: int) -> Decision:
        return copy == 1


class PairedViews(MixPolicy):
    """Both views of one item, as a tuple ``(clean, degraded)``, for consistency losses. Length unchanged."""

    def decide(self, index: int, copy: int, epoch: int, seed: int) -> Decision:
        return (False, True)


class Bernoulli(MixPolicy):
    """Each item is degraded independently with probability ``p``, anew every epoch.

    Item ``i`` is degraded in epoch ``e`` exactly when ``u(seed, e, i) < p``, where ``u`` is a stable hash of its
    arguments mapped to ``[0, 1)`` (:func:`camdegrade.data.item_uniform`). The fraction degraded is ``p`` in
    expectation, not exactly; use :class:`Ratio` for an exact fraction. :class:`BatchDegrade` with the same ``p``
    and seed degrades exactly the same items.
    """

    def __init__(self, p: float) -> None:
        self.p = check_probability(p)

    def probability(self, epoch: int) -> float:
        return self.p

    def decide(self, index: int, copy: int, epoch: int, seed: int) -> Decision:
        return item_uniform(seed, epoch, index) < self.probability(epoch)


class Ratio(MixPolicy):
    """Exactly ``k`` of every ``m`` consecutive items are degraded, and each item is degraded in ``k`` of every
    ``m`` epochs.

    Item ``i`` is degraded in epoch ``e`` exactly when ``(i + e) % m < k``. The pattern ignores the seed (the seed
    still draws the degradations themselves).
    """

    def __init__(self, k: int, m: int) -> None:
        self.m = check_int("m", m, minimum=1)
        self.k = check_int("k", k, minimum=0)
        if self.k > self.m:
            raise ValueError(f"k must be at most m (k of every m items are degraded), got k={k}, m={m}")

    def decide(self, index: int, copy: int, epoch: int, seed: int) -> Decision:
        return (index + epoch) % self.m < self.k


class Alternate(MixPolicy):
    """Every other item is degraded, and every item flips between clean and degraded from epoch to epoch.

    Item ``i`` is degraded in epoch ``e`` exactly when ``i + e`` is odd: items 1, 3, 5, ... in epoch 0.
    """

    def decide(self, index: int, copy: int, epoch: int, seed: int) -> Decision:
        return (index + epoch) % 2 == 1


class Schedule(Bernoulli):
    """:class:`Bernoulli` with a probability that changes over epochs (e.g. a curriculum from clean to degraded).

    Item ``i`` is degraded in epoch ``e`` exactly when ``u(seed, e, i) < p(e)``.

    Args:
        p: one probability per epoch (the last one holds for later epochs), or a picklable callable
            ``epoch -> probability`` (a module-level function, not a lambda, if workers are spawned).

    Examples:
        >>> Schedule([0.0, 0.25, 0.5]).probability(7)
        0.5
        >>> Schedule.linear(0.0, 1.0, epochs=5).probability(2)
        0.5
    """

    def __init__(self, p: Sequence[float] | Callable[[int], float]) -> None:
        if callable(p):
            self.p_of_epoch: Sequence[float] | Callable[[int], float] = p
        elif isinstance(p, Sequence) and not isinstance(p, str) and len(p) > 0:
            self.p_of_epoch = tuple(check_probability(value) for value in p)
        else:
            raise TypeError(f"p must be a non-empty sequence of probabilities or a callable epoch -> p, got p={p!r}")

    @classmethod
    def linear(cls, start: float, end: float, epochs: int) -> Schedule:
        """``p`` moving linearly from ``start`` at epoch 0 to ``end`` at epoch ``epochs - 1``, then held."""
        check_int("epochs", epochs, minimum=1)
        start, end = check_probability(start), check_probability(end)
        steps = max(epochs - 1, 1)
        return cls([start + (end - start) * min(epoch, steps) / steps for epoch in range(epochs)])

    def probability(self, epoch: int) -> float:
        if callable(self.p_of_epoch):
            return check_probability(self.p_of_epoch(epoch))
        return self.p_of_epoch[min(epoch, len(self.p_of_epoch) - 1)]


_NAMED: dict[str, Callable[[], MixPolicy]] = {"union": Union, "pair": PairedViews, "alternate": Alternate}


def resolve_policy(policy: MixPolicy | str) -> MixPolicy:
    """A policy object from itself or from one of the names ``"union"``, ``"pair"``, ``"alternate"``."""
    if isinstance(policy, MixPolicy):
        return policy
    if isinstance(policy, str) and policy.lower() in _NAMED:
        return _NAMED[policy.lower()]()
    raise ValueError(
        "policy must be a MixPolicy (Union(), PairedViews(), Bernoulli(p), Alternate(), Ratio(k, m), "
        f"Schedule(...)) or one of {sorted(_NAMED)}, got policy={policy!r}"
    )
