"""How the search's changes are evaluated faster with the same result.

- The strength-check set's gap of each profile is kept by the profile's content (:class:`GapsByContent`): the same
  profile is reached more than once (a strength search's knot at 1 is the candidate as fitted; a refit measures the
  option it chose again), and its check-set simulations draw from fixed seeds, so measuring it again gives the same
  number. The key is :class:`~camdegrade._runtime.outputs.ProfileKeys`' digest of the network's and every stage's
  tensors and settings, the one :meth:`~camdegrade.profile.CameraProfile.simulate` already trusts to reuse an output.
- A round's changes are evaluated side by side when torch has two or more threads (:func:`evaluated`), each on one
  torch thread, their progress lines said in the order the changes were planned: every change is fitted and
  measured from its own seeded draws, so each gives the bytes it gives alone.
"""

from __future__ import annotations

import dataclasses
from typing import Protocol

from camdegrade._runtime.outputs import ProfileKeys
from camdegrade._runtime.threads import side_by_side
from camdegrade.diagnose.attribution.changes import Change, Plan
from camdegrade.diagnose.attribution.round_view import Round
from camdegrade.diagnose.heldout import HeldOut
from camdegrade.profile import CameraProfile

__all__ = ["Evaluating", "GapsByContent", "evaluated"]


class Evaluating(Round, Protocol):
    """What :func:`evaluated` needs of a search round (:class:`~camdegrade.diagnose.attribution.search.Round`, a
    dataclass whose ``say`` a copy replaces): what a change reads of it, and how one plan is made and measured."""

    def evaluate(self, plan: Plan) -> Change: ...


class GapsByContent:
    """``gaps(profile)``: ``check``'s gap of ``profile`` (its statistics against the check set's real ones, on the
    check set's fixed scale), measured once per profile content."""

    def __init__(self, check: HeldOut) -> None:
        self.check = check
        self._gaps: dict[str, float] = {}

    def __call__(self, profile: CameraProfile) -> float:
        key = ProfileKeys(profile).whole()
        if key not in self._gaps:
            self._gaps[key] = self.check.gap(self.check.statistics(profile)[0])
        return self._gaps[key]

    def __len__(self) -> int:
        return len(self._gaps)


def evaluated(round_: Evaluating, plans: list[Plan]) -> list[Change]:
    """Each plan's change on top of ``round_``'s profile, in the order of ``plans`` (side by side where torch has the
    threads: :func:`~camdegrade._runtime.threads.side_by_side`), and each one's progress lines said in that order."""
    if len(plans) > 1:
        round_.sources(), round_.check_gap()  # the round's shared values, computed once before the workers need them

    def one(plan: Plan) -> tuple[Change, list[str]]:
        lines: list[str] = []
        return dataclasses.replace(round_, say=lines.append).evaluate(plan), lines  # type: ignore[type-var]

    # the slowest first (the network's fine-tune: a third of the work), so that no worker waits alone at the end
    started = sorted(range(len(plans)), key=lambda index: plans[index].kind.kind != "network")
    done = side_by_side([lambda plan=plans[index]: one(plan) for index in started])
    results = [result for _, result in sorted(zip(started, done, strict=True), key=lambda item: item[0])]
    for _, lines in results:
        for line in lines:
            round_.say(line)
    return [change for change, _ in results]
