"""The diagnosis' learned critic: how well a small CNN tells the captures from the simulations, before and after the
accepted changes, and what it sees (its surest patches and its accuracy by group,
:mod:`camdegrade.measures.critic_explain`)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from torch import Tensor

from camdegrade.fitting.pairset import simulate
from camdegrade.measures.critic import CriticResult
from camdegrade.measures.critic_explain import CriticExplanation, explained_critic_test
from camdegrade.profile import CameraProfile

#: Surest patches shown per class, and at most this many of a class from one pair.
SUREST = 4
SUREST_PER_PAIR = 2


@dataclass
class Critique:
    """One critic's score and what it saw, and the names of the pairs it was trained and scored on."""

    result: CriticResult
    explanation: CriticExplanation
    trained_on: list[str]
    scored_on: list[str]

    def to_dict(self) -> dict:
        """The critic's JSON: its score, its accuracy by texture, intensity, colour and position (``by_group``
        with the tercile ``group_edges``), the surest patches' places, and the pairs behind it."""
        explained = self.explanation.to_dict()
        return {
            **self.result.to_dict(),
            "by_group": explained["groups"],
            "group_edges": explained["edges"],
            "surest": explained["surest"],
            "trained_on": list(self.trained_on),
            "scored_on": list(self.scored_on),
        }


def critiques(
    profiles: Sequence[tuple[str, CameraProfile, list[Tensor]]],
    calibration: list[tuple[Tensor, Tensor]],
    held: list[tuple[Tensor, Tensor]],
    names: tuple[list[str], list[str]],
    seed: int,
    say: Callable[[str], None],
) -> dict[str, Critique]:
    """For each ``(label, profile, its held-out simulations)``, a critic trained on the calibration pairs and scored
    on the held-out ones; ``names`` are the calibration and the held-out pairs' names."""
    cal_cleans, cal_reals = [c for c, _ in calibration], [r for _, r in calibration]
    held_cleans, held_reals = [c for c, _ in held], [r for _, r in held]
    out = {}
    for label, profile, held_sims in profiles:
        cal_sims = simulate(profile, cal_cleans, seed, stream="critic-calibration")
        result, explanation = explained_critic_test(
            (cal_cleans, cal_reals, cal_sims),
            (held_cleans, held_reals, held_sims),
            seed,
            k=SUREST,
            per_pair=SUREST_PER_PAIR,
        )
        out[label] = Critique(result, explanation, list(names[0]), list(names[1]))
        say(f"critic {label}: {result.describe()}")
    return out
