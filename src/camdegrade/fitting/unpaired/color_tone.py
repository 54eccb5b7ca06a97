"""White balance and a tone curve from two sets of different scenes, by quantile matching: the clean set's channel
quantiles mapped onto the captures', each kept where it changes more than its floor and more than the sets' content
moves it by (:mod:`camdegrade.fitting.unpaired.judges`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import Tensor

from camdegrade.effects import Color, Effect, Tone
from camdegrade.effects._fitting import minimize
from camdegrade.fitting.unpaired.bench import UnpairedFit, UnpairedStep
from camdegrade.fitting.unpaired.judges import significant, split_half_error
from camdegrade.functional import linear_to_srgb, srgb_to_linear
from camdegrade.functional.tone import tone_curve

__all__ = ["ColorToneMatch", "judge_color_tone", "propose_color_tone"]

#: Quantiles of each channel compared (1-D optimal transport between two sets is the map between their quantiles).
QUANTILES = torch.linspace(0.01, 0.99, 99, dtype=torch.float64)
#: At most this many pixels of each image enter the quantiles (evenly strided).
PIXELS_PER_IMAGE = 20_000
#: A white-balance gain is kept when some channel's differs from 1 by more than this (log units, about 3 %) ...
COLOR_FLOOR = 0.03
#: ... a tone curve when it moves some value by more than this (about 5 8-bit levels).
TONE_FLOOR = 0.02
#: The values at which a tone curve's change is tested.
TONE_GRID = torch.linspace(0.1, 0.9, 9, dtype=torch.float64)


def pixel_sample(image: Tensor) -> Tensor:
    """``(3, P)``: at most :data:`PIXELS_PER_IMAGE` of the image's pixels (evenly strided), in linear light."""
    flat = image.reshape(3, -1)
    return srgb_to_linear(flat[:, :: max(1, flat.shape[1] // PIXELS_PER_IMAGE)].double())


def channel_quantiles(samples: Sequence[Tensor]) -> Tensor:
    """``(3, len(QUANTILES))`` quantiles of each channel of the pooled :func:`pixel_sample` s."""
    return torch.quantile(torch.cat(list(samples), 1), QUANTILES, dim=1).T


def color_tone_estimate(real: Tensor, clean: Tensor) -> tuple[Tensor, Tone]:
    """White-balance gains ``(3,)`` and a tone curve mapping the quantiles ``clean`` onto ``real`` (both
    :func:`channel_quantiles`), fitted together by L-BFGS (see :func:`fit_color_tone`)."""
    target = linear_to_srgb(real.clamp(0, 1))
    weight = (((QUANTILES >= 0.02) & (QUANTILES <= 0.98))[None] & (real < 0.99) & (real > 1e-4)).double()
    log_gains = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    log_gamma, black, log_range = (torch.zeros((), dtype=torch.float64, requires_grad=True) for _ in range(3))
    zero = torch.zeros((), dtype=torch.float64)

    def balanced() -> Tensor:  # an overall gain is the curve's levels' to say: the gains' geometric mean is 1
        return (log_gains - log_gains.mean()).exp()

    def loss() -> Tensor:
        source = linear_to_srgb((clean * balanced()[:, None]).clamp(0, 1))
        predicted = tone_curve(source, log_gamma.exp(), black, black + log_range.exp(), zero)
        return (weight * (predicted - target).pow(2)).sum() / weight.sum()

    minimize([log_gains, log_gamma, black, log_range], loss, max_iter=200)
    with torch.no_grad():
        tone = Tone(float(log_gamma.exp()), float(black), float(black + log_range.exp()))
        return balanced().clamp(0.05, 16.0).detach(), tone


@dataclass(frozen=True)
class ColorToneProposal:
    """White-balance gains and a tone curve fitted on the whole sets, and the pixel samples they came from (the
    judge fits them again on halves of both)."""

    real_samples: list[Tensor]
    clean_samples: list[Tensor]
    gains: Tensor
    tone: Tone

    def estimate(self, real_indices: list[int], clean_indices: list[int]) -> Tensor:
        """The change the gains and curve fitted on these images make: log gains, then the curve less the identity
        on :data:`TONE_GRID`."""
        real = channel_quantiles([self.real_samples[i] for i in real_indices])
        clean = channel_quantiles([self.clean_samples[i] for i in clean_indices])
        return _change(*color_tone_estimate(real, clean))


def propose_color_tone(captures: Sequence[Tensor], cleans: Sequence[Tensor]) -> ColorToneProposal:
    """White-balance gains and a tone curve that map the clean set's channel quantiles onto the captures'.

    The gains (a diagonal :class:`~camdegrade.effects.Color`, linear light) and the
    :class:`~camdegrade.effects.Tone` curve (one for the three channels) are fitted together: least squares between
    the sRGB quantiles 0.02–0.98 of the captures and those of the clean set through gains and curve. An overall
    gain and the curve's levels trade against each other, so the gains are a white balance (their geometric mean
    is 1) and the curve carries the exposure.

    References:
        G. Peyré, M. Cuturi, "Computational Optimal Transport", Foundations and Trends in Machine Learning 11, 2019
        (§2.6: in one dimension the optimal map sends each quantile to the same quantile).
    """
    real_samples, clean_samples = [pixel_sample(image) for image in captures], [pixel_sample(image) for image in cleans]
    gains, tone = color_tone_estimate(channel_quantiles(real_samples), channel_quantiles(clean_samples))
    return ColorToneProposal(real_samples, clean_samples, gains, tone)


def judge_color_tone(
    proposal: ColorToneProposal, seed: int = 0, *, test: bool = True
) -> tuple[Color | None, Tone | None, dict]:
    """The gains kept where some channel's differs from 1 by more than :data:`COLOR_FLOOR`, the curve where it moves
    some value by more than :data:`TONE_FLOOR` (fitted alone where the gains are not kept), each by more than
    :data:`~camdegrade.fitting.unpaired.judges.SIGNIFICANCE` standard errors of the content
    (:func:`~camdegrade.fitting.unpaired.judges.split_half_error`; ``test=False``: by its floor alone, for an
    intermediate round); and the record."""
    change = _change(proposal.gains, proposal.tone)
    no_test = torch.zeros_like(change)
    captures, cleans = len(proposal.real_samples), len(proposal.clean_samples)
    error = split_half_error(proposal.estimate, captures, cleans, seed) if test else no_test
    color_kept = significant(change[:3], error[:3], COLOR_FLOOR)
    gains, tone = proposal.gains, proposal.tone
    if not color_kept:
        real, clean = channel_quantiles(proposal.real_samples), channel_quantiles(proposal.clean_samples)
        gains, tone = torch.ones(3, dtype=torch.float64), _tone_between(clean, linear_to_srgb(real.clamp(0, 1)))
    tone_change = _curve(tone, TONE_GRID) - TONE_GRID
    tone_kept = significant(tone_change, error[3:], TONE_FLOOR)
    notes = {
        "gains": [round(float(g), 4) for g in change[:3].exp()],
        "gains_error": [round(float(e), 4) for e in error[:3]],
        "tone_change": [round(float(v), 4) for v in tone_change],
        "tone_error": [round(float(e), 4) for e in error[3:]],
    }
    color = Color(torch.diag(gains).float()) if color_kept else None
    return color, tone if tone_kept else None, notes


def _change(gains: Tensor, tone: Tone) -> Tensor:
    return torch.cat([gains.log(), _curve(tone, TONE_GRID) - TONE_GRID])


@dataclass(frozen=True)
class ColorToneMatch(UnpairedStep):
    """The colour and tone step (it needs the clean set): gains and curve on the sets averaged down, the clean set
    through the chain's optics first; ``test=False`` for the first round (its floors alone), a second round with
    the split-half test once the blur is in the chain."""

    name: ClassVar[str] = "color_tone"
    kinds: ClassVar[tuple[type[Effect], ...]] = (Color, Tone)
    needs_clean: ClassVar[bool] = True
    test: bool = True

    def propose(self, fit: UnpairedFit) -> ColorToneProposal:
        chain = fit.deterministic(optics_only=True)
        sources = fit.simulate(chain, fit.sets.small_cleans, "unpaired-deterministic")
        return propose_color_tone(fit.sets.small_captures, sources)

    def judge(self, fit: UnpairedFit, proposal: ColorToneProposal) -> dict:
        color, tone, notes = judge_color_tone(proposal, fit.seed, test=self.test)
        for kind, stage in ((Color, color), (Tone, tone)):
            fit.keep(stage if fit.wants(kind) else None, kind)
        fit.say(f"colour and tone: gains {notes['gains']}, tone curve change {notes['tone_change']}")
        return notes


def _tone_between(clean: Tensor, target: Tensor) -> Tone:
    """The tone curve alone from the clean quantiles (linear) to the captures' (sRGB)."""
    source = linear_to_srgb(clean.clamp(0, 1))
    return Tone.fit(source[:, None, :].float(), target[:, None, :].float())


def _curve(tone: Tone, values: Tensor) -> Tensor:
    return tone_curve(values, *(getattr(tone, key).double() for key in ("gamma", "black", "white", "exposure")))
