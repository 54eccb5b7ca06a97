"""An unpaired fit in progress: the two sets and what is measured of them once (:class:`Measured`), the stages kept
so far in the chain's order, every step's record, and why a step does not run (the loop of
:mod:`camdegrade.fitting.steps.base`)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

from torch import Tensor

from camdegrade.effects import (
    JPEG,
    Blur,
    Color,
    Effect,
    FrequencyResponse,
    LearnedTexture,
    Noise,
    Resolution,
    Sharpen,
    Tone,
    Vignetting,
)
from camdegrade.fitting.steps.base import FitStep
from camdegrade.fitting.unpaired.images import ImageSet
from camdegrade.functional.analysis.noise import NoiseSums
from camdegrade.profile import CameraProfile

__all__ = ["AREA_ORDER", "CHAIN_ORDER", "NEEDS_CLEAN", "Log", "Measured", "UnpairedFit", "UnpairedStep"]

#: The stages' order in the fitted chain (physical: optics, sensor, ISP, codec; the ISP's upscale last before the
#: codec, so the sensor's noise and the ISP's sharpening are upsampled with the image; the learned texture after
#: everything it was trained after).
CHAIN_ORDER = tuple(
    kind.name
    for kind in (Blur, Vignetting, Noise, Color, Tone, Sharpen, FrequencyResponse, Resolution, JPEG, LearnedTexture)
)
#: The order with a sensor that reads its pixels' areas (:mod:`~camdegrade.fitting.unpaired.steps.area_sensor`): the
#: ISP sharpens the image it upscaled, so the sharpening and the detail response come after the upscale.
AREA_ORDER = tuple(name for name in CHAIN_ORDER if name != Resolution.name)
AREA_ORDER = (
    *AREA_ORDER[: AREA_ORDER.index(Sharpen.name)],
    Resolution.name,
    *AREA_ORDER[AREA_ORDER.index(Sharpen.name) :],
)
#: Why a step that needs the clean set is not fitted without one.
NEEDS_CLEAN = "needs a clean set (--clean)"

Log = Callable[[str], None]


class UnpairedStep(FitStep):
    """A step of the unpaired fit: it runs where one of its effect ``kinds`` is asked for, with the clean set where
    it ``needs_clean``, and (a step that fits again) where it :meth:`applies`."""

    kinds: ClassVar[tuple[type[Effect], ...]] = ()
    needs_clean: ClassVar[bool] = False

    def applies(self, fit: UnpairedFit) -> bool:
        return True


@dataclass
class Measured:
    """What an unpaired fit measures of its sets once: the clean images (or stand-ins) the noise is simulated on
    and the crops the spectrum is compared on, the captures' flat-pixel noise, both sets averaged down (colour,
    tone, vignetting) with their ring profiles, and the captures' log spectra and their mean."""

    noise_crops: list[Tensor]
    spectrum_crops: list[Tensor]
    real_noise: NoiseSums
    small_captures: list[Tensor]
    small_cleans: list[Tensor]
    real_rings: Tensor
    clean_rings: Tensor
    real_spectra: Tensor
    real_spectrum: Tensor
    #: The captures' step-edge spread (:class:`~camdegrade.fitting.unpaired.steps.edges.EdgeSpread`), measured when
    #: first asked for.
    edge_spread: Any = None
    #: The captures' flat-pixel noise read at the noise stage's scale
    #: (:func:`~camdegrade.fitting.unpaired.steps.noise.captures_noise`), measured when first asked for.
    fine_noise: NoiseSums | None = None


class UnpairedFit:
    """The state of one unpaired fit: the stages so far, each step's record, and the sets it simulates."""

    def __init__(
        self, captures: ImageSet, cleans: ImageSet | None, measured: Measured, wanted: list[str], seed: int, say: Log
    ) -> None:
        self.captures, self.cleans, self.sets = captures, cleans, measured
        self.wanted, self.seed, self.say = wanted, seed, say
        self.stages: dict[str, Effect] = {}
        self.records: dict[str, Any] = {}
        self.not_fitted: dict[str, str] = {}
        self.warnings: list[str] = []

    def chain(self, **replaced: Effect | None) -> list[Effect]:
        """The kept stages in the chain's order (:data:`AREA_ORDER` with an area-sampling sensor), with ``replaced``
        ones in place (``None``: left out)."""
        stages = {**self.stages, **replaced}
        area = getattr(stages.get(Resolution.name), "sample", None) == "area"
        return [stages[key] for key in (AREA_ORDER if area else CHAIN_ORDER) if stages.get(key) is not None]

    def deterministic(self, *, optics_only: bool = False, **replaced: Effect | None) -> list[Effect]:
        """The chain's deterministic centre without its codec (what the set statistics of colour, tone and
        vignetting see), or only its optics stages."""
        chain = [effect.without_randomness() for effect in self.chain(jpeg=None, **replaced)]
        return [effect for effect in chain if effect is not None and (effect.stage == "optics" or not optics_only)]

    def simulate(self, chain: list[Effect] | CameraProfile, images: Sequence[Tensor], stream: str) -> list[Tensor]:
        """``images`` through ``chain`` (:meth:`CameraProfile.simulate`: image ``i`` seeded by ``(seed, stream, i)``),
        stored as 8-bit values."""
        profile = chain if isinstance(chain, CameraProfile) else CameraProfile(None, chain)
        return profile.simulate(images, self.seed, stream=stream, eight_bit=True)

    def stages_after(self, kind: type[Effect]) -> list[str]:
        """The kept stages that come after ``kind``'s place in the chain."""
        later = CHAIN_ORDER[CHAIN_ORDER.index(kind.name) + 1 :]
        return [name for name in later if self.stages.get(name) is not None]

    def wants(self, *kinds: type[Effect]) -> bool:
        """Whether any of these stages is to be fitted."""
        return any(kind.name in self.wanted for kind in kinds)

    def keep(self, stage: Effect | None, *kinds: type[Effect]) -> None:
        """``stage`` in the chain (nothing for ``None``), in place of the stages of ``kinds`` (their refit), once its
        values are in the stage's range (:meth:`~camdegrade.effects.Effect.check_values`, what saving the profile
        checks). A stage out of range is not kept and the fit goes on without it, with a warning that names it and
        its value: the sets differ by more than the stage models (the captures' scenes darker than the clean
        images', a tone no curve of the stage reaches), which one stage's refusal must not turn into no profile."""
        if stage is not None:
            try:
                stage.check_values()
            except ValueError as error:
                reason = (
                    f"the {stage.name} stage fitted to these images is outside its range ({error}), so it is not "
                    "kept: the captures differ from the clean images by more than the stage models (photos of "
                    "darker or other scenes than the clean images'?)"
                )
                self.not_fitted[stage.name] = reason
                self.warnings.append(reason)
                self.say(f"{stage.name}: not kept, outside its range ({error})")
                return
        for kind in kinds:
            self.stages.pop(kind.name, None)
        if stage is not None:
            self.stages[stage.name] = stage

    def not_fit(self, kinds: Sequence[type[Effect]], reason: str) -> None:
        """Record why the asked-for stages of ``kinds`` are not fitted."""
        for kind in kinds:
            if self.wants(kind):
                self.not_fitted[kind.name] = reason

    def unmet(self, step: UnpairedStep) -> str | None:
        if not step.applies(self) or not self.wants(*step.kinds):
            return ""
        return NEEDS_CLEAN if step.needs_clean and self.cleans is None else None

    def skip(self, step: UnpairedStep, reason: str) -> None:
        if reason:
            self.not_fit(step.kinds, reason)
