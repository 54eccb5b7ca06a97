"""What the kinds of change, their placements and the cause rule read of the search round they are made in: the
round's view as protocols (:class:`~camdegrade.diagnose.attribution.search.Round` and its ``Search`` are what runs), so
that the search imports the kinds and the kinds name no class of the search."""

from __future__ import annotations

from typing import Any, Protocol

from torch import Tensor

from camdegrade.effects import Effect
from camdegrade.measures import StatisticSet
from camdegrade.profile import CameraProfile

__all__ = ["Made", "Round", "SearchView"]

#: What making a change gives: the changed profile, the stage it added or refitted (if any), and its description.
Made = tuple[CameraProfile, Effect | None, str]


class SearchView(Protocol):
    """What a change reads of the search it is made in (:class:`~camdegrade.diagnose.attribution.search.Search`)."""

    cleans: list[Tensor]
    reals: list[Tensor]
    seed: int
    held: Any
    baseline: Any
    noise_pairs: int

    def fit_in_chain(self, profile: CameraProfile, kind: type[Effect]) -> Effect: ...


class Round(Protocol):
    """What a change reads of the round it is made in (:class:`~camdegrade.diagnose.attribution.search.Round`)."""

    search: SearchView
    current: CameraProfile
    stats: StatisticSet
    say: Any

    def sources(self, profile: CameraProfile | None = None) -> list[Tensor]: ...

    def check_gap(self, profile: CameraProfile | None = None) -> float: ...

    def refined(self, effect: Effect, base: CameraProfile, *, explore: bool = False) -> tuple[Effect, float]: ...
