"""The diagnosis' learned critic: how well a small CNN tells the captures from the simulations, before and after the
accepted changes, and what it sees (its surest patches and its accuracy by group,
:mod:`camdegrade.measures.critic.explain`).

**Not optimistic.** The changes are fitted on the calibration pairs; a critic trained there would learn from
simulations the fit has bent towards those very captures, and would then underrate how far the simulation is from
the camera (issue 24: 0.87 reported where an independent critic found 0.99). So the critic never sees a
calibration pair: the held-out pairs are split again by scene
(:func:`~camdegrade.measures.critic.alternate_scenes`), and for each profile (the one given, the one with the
changes) a fresh critic is trained on one part and scores the other, and a second the other way round
(:func:`~camdegrade.measures.critic.explain.crossfit_critic_test`): every held-out pair is scored by a critic that
saw neither it nor any pair the change was fitted on. The accuracy is pooled over both folds, its 95 % interval a
bootstrap over the held-out pairs; each fold's own accuracy is reported too (how much the verdict depends on which pairs
trained the critic). Both profiles use the same folds, so before and after are comparable.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from torch import Tensor

from camdegrade.measures.critic import CriticResult, alternate_scenes
from camdegrade.measures.critic.explain import CriticExplanation, crossfit_critic_test

__all__ = ["CRITIC_CHANCE", "SUREST", "SUREST_PER_PAIR", "Critique", "critiques"]

#: The critic "tells them apart" when the lower end of its 95 % interval is above this.
CRITIC_CHANCE = 0.55
#: Surest patches shown per class, and at most this many of a class from one pair.
SUREST = 4
SUREST_PER_PAIR = 2


@dataclass
class Critique:
    """One two-fold critic's score and what it saw, and its folds: the held-out pairs each fold's critic was
    trained on and scored on, and its accuracy."""

    result: CriticResult
    explanation: CriticExplanation
    folds: list[dict]

    @property
    def scored_on(self) -> list[str]:
        """The names of the scored pairs in the order the explanation numbers them."""
        return [name for fold in self.folds for name in fold["scored_on"]]

    def to_dict(self) -> dict:
        """The critic's JSON: its score, its accuracy by texture, intensity, colour and position (``by_group``
        with the tercile ``group_edges``), the surest patches' places, and its folds."""
        explained = self.explanation.to_dict()
        return {
            **self.result.to_dict(),
            "by_group": explained["groups"],
            "group_edges": explained["edges"],
            "surest": explained["surest"],
            "folds": self.folds,
            "scored_on": self.scored_on,
        }


def critiques(
    simulations: Sequence[tuple[str, list[Tensor]]],
    held: list[tuple[Tensor, Tensor]],
    names: Sequence[str],
    scenes: Sequence[str],
    seed: int,
    say: Callable[[str], None],
    image_only: bool = False,
) -> dict[str, Critique]:
    """For each ``(label, a profile's simulations of the held-out pairs)``, a two-fold critic on the held-out pairs
    (see the module); ``names`` and ``scenes`` are the held-out pairs'. With ``image_only`` the critic sees the
    image alone (what a model trained on the simulation sees), not the clean source beside it."""
    trains = alternate_scenes(scenes)
    sides = [[names[i] for i, t in enumerate(trains) if t is side] for side in (True, False)]
    cleans, reals = [c for c, _ in held], [r for _, r in held]
    out = {}
    for label, sims in simulations:
        result, explanation, accuracies = crossfit_critic_test(
            (cleans, reals, sims), trains, seed, k=SUREST, per_pair=SUREST_PER_PAIR, image_only=image_only
        )
        folds = [
            {"trained_on": sides[0], "scored_on": sides[1], "accuracy": round(accuracies[0], 4)},
            {"trained_on": sides[1], "scored_on": sides[0], "accuracy": round(accuracies[1], 4)},
        ]
        out[label] = Critique(result, explanation, folds)
        say(
            f"critic {label}: {result.describe()} (two folds of the held-out pairs: {accuracies[0]:.2f} and "
            f"{accuracies[1]:.2f})"
        )
    return out
