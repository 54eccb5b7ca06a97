"""The strength-check set's gap of each profile the search measures, kept by the profile's content: the same profile
is reached more than once (a strength search's knot at 1 is the candidate as fitted; a refit measures the option it
chose again), and its check-set simulations draw from fixed seeds, so measuring it again gives the same number.

The key is :class:`~camdegrade._outputs.ProfileKeys`' digest of the network's and every stage's tensors and settings,
the one :meth:`~camdegrade.profile.CameraProfile.simulate` already trusts to reuse an output.
"""

from __future__ import annotations

from camdegrade._outputs import ProfileKeys
from camdegrade.diagnose.heldout import HeldOut
from camdegrade.profile import CameraProfile

__all__ = ["GapsByContent"]


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
