"""A paired fit's optional last step: a learned texture stage trained after the profile on the training pairs by the
two-sample objective plus an L2 term against the aligned captures (pix2pix's L1 + GAN, in squares;
:func:`~camdegrade.fitting.two_sample.train.fit_two_sample` with ``paired=True``), kept where, on the validation
pairs, a fresh image-only critic (never the one it was trained against) tells the sampled output from the captures
less easily and the deterministic output's PSNR falls by at most :data:`MAX_PSNR_LOSS_DB` (issue 43's rule for
adopting it). Not in any recipe by default: on City100 the built-in with such a stage measured 0.643 ± 0.04 against
0.648 ± 0.04 (8 critics), PSNR 30.87 against 30.81 dB (docs/results.md); the recipe option ``learned_texture``
turns it on.

References:
    P. Isola, J.-Y. Zhu, T. Zhou, A. A. Efros, "Image-to-Image Translation with Conditional Adversarial Networks",
    CVPR 2017.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from camdegrade.effects import LearnedTexture
from camdegrade.fitting.steps.base import FitStep, PairedFit, Verdict
from camdegrade.fitting.two_sample.train import TwoSampleOptions, fit_two_sample
from camdegrade.measures.critic import repeated_critic_test
from camdegrade.measures.metrics import psnr

__all__ = ["JUDGE_PAIRS", "MAX_PSNR_LOSS_DB", "PIXEL_WEIGHT", "LearnedTexturePaired"]

#: The L2 term's weight against the aligned captures (City100: 100 keeps PSNR within 0.1 dB).
PIXEL_WEIGHT = 100.0
#: The deterministic output's PSNR on the validation pairs may fall by at most this much with the stage.
MAX_PSNR_LOSS_DB = 0.3
#: At most this many validation pairs judge it.
JUDGE_PAIRS = 16


@dataclass(frozen=True)
class LearnedTexturePaired(FitStep):
    """The learned texture step of a paired fit, last, of ``steps`` training steps; recorded in
    ``fitted['learned_texture']``: the fresh critic and PSNR without and with the stage, and whether kept."""

    name: ClassVar[str] = LearnedTexture.name
    needs_network: ClassVar[bool] = True
    steps: int = 1200
    critic_seeds: int = 2

    def propose(self, fit: PairedFit) -> tuple[LearnedTexture, dict[str, Any]] | Verdict:
        if any(isinstance(effect, LearnedTexture) for effect in fit.profile.effects):
            return Verdict({"kept": False, "reason": "the profile already has a learned texture stage"})
        cleans = [clean for clean, _ in fit.train_pairs]
        captures = [captured for _, captured in fit.train_pairs]
        options = TwoSampleOptions(pixel_weight=PIXEL_WEIGHT)
        return fit_two_sample(
            fit.profile, cleans, captures, seed=fit.seed, steps=self.steps, options=options, paired=True
        )

    def judge(self, fit: PairedFit, proposal: tuple[LearnedTexture, dict[str, Any]]) -> dict[str, Any]:
        stage, training = proposal
        pairs = fit.judge_pairs(JUDGE_PAIRS)
        cleans, captures = [clean for clean, _ in pairs], [captured for _, captured in pairs]
        scenes = [f"{index:04d}" for index in range(len(pairs))]
        rows = {}
        for label, profile in (("without", fit.profile), ("with", fit.profile.with_effects(stage))):
            sims = profile.simulate(cleans, fit.seed, stream="learned-check", eight_bit=True)
            means = profile.simulate(cleans, fit.seed, stream="learned-check", deterministic=True)
            critic = repeated_critic_test((cleans, captures, sims), scenes, self.critic_seeds, image_only=True)
            score = sum(psnr(mean, captured) for mean, captured in zip(means, captures, strict=True)) / len(pairs)
            rows[label] = {"critic": round(critic.accuracy, 4), "psnr": round(score, 3)}
        kept = (
            rows["with"]["critic"] < rows["without"]["critic"]
            and rows["without"]["psnr"] - rows["with"]["psnr"] <= MAX_PSNR_LOSS_DB
        )
        fit.say(
            f"learned texture: {'kept' if kept else 'dropped'} (validation critic {rows['without']['critic']:.2f} -> "
            f"{rows['with']['critic']:.2f}, PSNR {rows['without']['psnr']:.2f} -> {rows['with']['psnr']:.2f} dB)"
        )
        fit.keep(kept, stage)
        return {"kept": kept, **rows, "steps": self.steps, "training_seconds": training["seconds"]}
