"""The steps of a paired fit besides its network, one :class:`FitStep` a module, and their registry: a recipe names
its steps (:attr:`~camdegrade.fitting.FitConfig.steps`) from :data:`STEPS`, whose order is where a step joins a recipe
that leaves it out. Adding a step: its module (options as dataclass fields, :meth:`FitStep.propose` and
:meth:`FitStep.judge`), one line here and its test. The network step (:mod:`camdegrade.fitting.steps.network`) is
every paired fit's, placed by the recipe after the steps it is trained through."""

from camdegrade.fitting.evidence.jitter_step import JitterMatch
from camdegrade.fitting.evidence.mosaic_step import MosaicRejudged
from camdegrade.fitting.steps.base import FitStep, PairedFit, Verdict, run_steps
from camdegrade.fitting.steps.denoise import DenoiseMatch
from camdegrade.fitting.steps.effects import EffectStages
from camdegrade.fitting.steps.learned import LearnedTexturePaired
from camdegrade.fitting.steps.resolution import ResamplerKernel, SensorResolution
from camdegrade.fitting.steps.response import ResponseMatch
from camdegrade.fitting.steps.texture import TextureMatch

#: Step name → its class, in the order a paired fit runs them.
STEPS: dict[str, type[FitStep]] = {
    SensorResolution.name: SensorResolution,
    EffectStages.name: EffectStages,
    ResamplerKernel.name: ResamplerKernel,
    TextureMatch.name: TextureMatch,
    DenoiseMatch.name: DenoiseMatch,
    ResponseMatch.name: ResponseMatch,
    MosaicRejudged.name: MosaicRejudged,
    JitterMatch.name: JitterMatch,
    LearnedTexturePaired.name: LearnedTexturePaired,
}

__all__ = ["STEPS", "FitStep", "PairedFit", "Verdict", "run_steps"]
