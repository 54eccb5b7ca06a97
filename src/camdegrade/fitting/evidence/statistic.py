"""An evidence stage judged by one statistic of the captures: the statistic of the judged captures, of the sampled
simulation without the stage and with it, whether the stage closes enough of that gap
(:func:`~camdegrade.fitting.steps.base.closes_gap`), and the share of the deterministic output's squared error it
removes. The JPEG stage (block-edge ratio) and the colour filter array (mosaic trace) are judged this way."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from torch import Tensor

from camdegrade.effects import Effect
from camdegrade.fitting.steps.base import PairedFit, closes_gap
from camdegrade.fitting.steps.noise_evidence import relative_gain
from camdegrade.profile import CameraProfile

__all__ = ["StatisticJudgement", "judge_by_statistic", "simulated_draws"]

Statistic = Callable[[Sequence[Tensor]], float]


@dataclass(frozen=True)
class StatisticJudgement:
    """``real``: the captures' statistic; ``without``/``within``: the sampled simulation's without and with the
    stage; ``kept``: whether the stage closes enough of the gap; ``gain``: its relative MSE gain; ``pairs`` and
    ``label``: how many pairs it was judged on, and which (:attr:`PairedFit.evidence_pairs`)."""

    real: float
    without: float
    within: float
    kept: bool
    gain: float
    pairs: int
    label: str

    def record(self, key: str, gap: str) -> dict[str, Any]:
        """The record's part this judgement fills: ``{key}_real``, ``{key}_without``, ``{key}_with``, the evidence,
        the relative MSE gain and, for a stage not kept, the reason (``gap`` names the statistic's gap)."""
        record: dict[str, Any] = {f"{key}_real": round(self.real, 3), f"{key}_without": round(self.without, 3)}
        record |= {f"{key}_with": round(self.within, 3), "evidence": self.label}
        record["relative_mse_gain"] = round(self.gain, 4)
        if not self.kept:
            left, found = abs(self.real - self.within), abs(self.real - self.without)
            record["reason"] = f"it leaves {left:.3f} of {gap} of {found:.3f}"
        return record

    def line_end(self) -> str:
        """The end of the log line: the relative MSE gain, the pairs and the decision."""
        decision = "kept" if self.kept else "dropped"
        return f"relative MSE gain {self.gain:.2%} on {self.pairs} {self.label} pair(s) -> {decision}"


def judge_by_statistic(
    fit: PairedFit,
    stage: Effect,
    statistic: Statistic,
    *,
    stream: str,
    eight_bit: bool,
    tolerance: float,
    share: float,
    draws: int = 1,
) -> StatisticJudgement:
    """``stage`` judged on ``fit``'s evidence pairs by ``statistic``: the profile sampled (seeds 0 to ``draws`` − 1,
    ``stream``, rounded to 8 bits where ``eight_bit``; the statistic of all draws together) without and with it; kept
    where what it leaves of the captures' gap is below ``tolerance`` or at most ``1 − share`` of it."""
    pairs, label = fit.evidence_pairs
    cleans, captures = (list(side) for side in zip(*pairs, strict=True))
    real = statistic(captures)
    without, within = (
        statistic(simulated_draws(profile, cleans, draws, stream=stream, eight_bit=eight_bit))
        for profile in (fit.profile, fit.profile.with_effects(stage))
    )
    kept = closes_gap(real, without, within, tolerance, share)
    gain = relative_gain(fit.profile, stage, cleans, captures)
    return StatisticJudgement(real, without, within, kept, gain, len(pairs), label)


def simulated_draws(
    profile: CameraProfile, cleans: Sequence[Tensor], draws: int, *, stream: str, eight_bit: bool
) -> list[Tensor]:
    """``profile``'s simulations of ``cleans`` with seeds 0 to ``draws`` − 1 (``stream``; rounded to 8 bits where
    ``eight_bit``), the draws one after the other."""
    return [
        image for seed in range(draws) for image in profile.simulate(cleans, seed, stream=stream, eight_bit=eight_bit)
    ]
