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
from camdegrade.functional.isp.tone import tone_curve

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


def exposure_between(real: Tensor, clean: Tensor, weight: Tensor) -> float:
    """The exposure (stops) that gives the clean quantiles the captures' mean linear light over the ``weight``-ed
    quantiles (both ``(3, Q)`` linear), within the tone stage's ±16 stops."""
    ratio = (weight * real).sum() / (weight * clean).sum().clamp_min(1e-12)
    return float(ratio.clamp_min(2.0**-16).log2().clamp(-16.0, 16.0))


def color_tone_estimate(real: Tensor, clean: Tensor, *, gains: bool = True) -> tuple[Tensor, Tone]:
    """White-balance gains ``(3,)`` (ones where not ``gains``) and a tone curve mapping the quantiles ``clean``
    onto ``real`` (both :func:`channel_quantiles`), fitted together by L-BFGS (see :func:`propose_color_tone`).

    The exposure comes first (:func:`exposure_between`), then the curve's gamma and levels: a dark camera is a gain
    in linear light before it is a curve. Fitted as levels and gamma alone, dead-leaves captures at 1 % of their
    scenes' values took gamma 16.2 with black −6.2 (past the stage's gamma of 16: the profile could not be saved;
    ``tests/test_unpaired_validity.py``; a real low-light camera, gamma 17.3)."""
    target = linear_to_srgb(real.clamp(0, 1))
    weight = (((QUANTILES >= 0.02) & (QUANTILES <= 0.98))[None] & (real < 0.99) & (real > 1e-4)).double()
    log_gains = torch.zeros(3, dtype=torch.float64, requires_grad=gains)
    log_gamma, black, log_range = (torch.zeros((), dtype=torch.float64, requires_grad=True) for _ in range(3))
    exposure = torch.tensor(exposure_between(real, clean, weight), dtype=torch.float64)

    def balanced() -> Tensor:  # an overall gain is the curve's levels' to say: the gains' geometric mean is 1
        return (log_gains - log_gains.mean()).exp()

    def loss() -> Tensor:
        source = linear_to_srgb((clean * balanced()[:, None]).clamp(0, 1))
        predicted = tone_curve(source, log_gamma.exp(), black, black + log_range.exp(), exposure)
        return (weight * (predicted - target).pow(2)).sum() / weight.sum()

    minimize([log_gains, log_gamma, black, log_range] if gains else [log_gamma, black, log_range], loss, max_iter=200)
    with torch.no_grad():
        tone = Tone(float(log_gamma.exp()), float(black), float(black + log_range.exp()), float(exposure))
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
        gains, tone = color_tone_estimate(real, clean, gains=False)
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
    the split-half test once the blur is in the chain. Captures of a monochrome camera (:func:`monochrome_notes`)
    get its colour stage (:func:`monochrome_color`; a warning where ``color`` is not fitted), the tone fitted grey
    to grey."""

    name: ClassVar[str] = "color_tone"
    kinds: ClassVar[tuple[type[Effect], ...]] = (Color, Tone)
    needs_clean: ClassVar[bool] = True
    test: bool = True

    def propose(self, fit: UnpairedFit) -> tuple[ColorToneProposal, dict | None]:
        monochrome = monochrome_notes(fit.sets.small_captures, fit.sets.small_cleans)
        optics = fit.deterministic(optics_only=True)
        if monochrome is not None and fit.wants(Color):  # the tone is then fitted grey to grey
            optics.append(monochrome_color())
        sources = fit.simulate(optics, fit.sets.small_cleans, "unpaired-deterministic")
        return propose_color_tone(fit.sets.small_captures, sources), monochrome

    def judge(self, fit: UnpairedFit, proposal: tuple[ColorToneProposal, dict | None]) -> dict:
        fitted, monochrome = proposal
        color, tone, notes = judge_color_tone(fitted, fit.seed, test=self.test)
        if monochrome is not None and fit.wants(Color):
            color, notes["monochrome"] = monochrome_color(), monochrome
            fit.say(f"colour: the captures are monochrome ({monochrome}): every channel the BT.601 luma")
        elif monochrome is not None and not any(w.startswith(MONOCHROME_WARNING) for w in fit.warnings):
            fit.warnings.append(f"{MONOCHROME_WARNING} ({monochrome}); fit 'color' to model it")
        for kind, stage in ((Color, color), (Tone, tone)):
            fit.keep(stage if fit.wants(kind) else None, kind)
        fit.say(f"colour and tone: gains {notes['gains']}, tone curve change {notes['tone_change']}")
        return notes


#: Captures whose red and blue differ from green by at most this on average (8-bit levels: rounding, a JPEG's
#: chroma of a grey image) while the clean images' differ by :data:`MONOCHROME_CONTRAST` times as much are a
#: monochrome camera's ...
MONOCHROME_LEVELS = 1.0
MONOCHROME_CONTRAST = 4.0
#: ... modelled exactly by a colour matrix whose three rows are the ITU-R BT.601 luma weights on the sRGB values:
#: the grey a JPEG's Y channel and PIL's ``convert("L")`` hold.
BT601_LUMA = (0.299, 0.587, 0.114)
MONOCHROME_WARNING = "the captures are monochrome and the clean images are not"


def chroma_levels(images: Sequence[Tensor]) -> float:
    """The mean absolute difference of red and of blue from green over the images' pixels (8-bit levels)."""
    values = [((image[0] - image[1]).abs().mean() + (image[2] - image[1]).abs().mean()) / 2 for image in images]
    return float(torch.stack(values).mean()) * 255.0


def monochrome_notes(captures: Sequence[Tensor], cleans: Sequence[Tensor]) -> dict | None:
    """``{"chroma_levels", "clean_chroma_levels"}`` where the captures are a monochrome camera's and the clean
    images are not (:data:`MONOCHROME_LEVELS`), else ``None``."""
    real, clean = chroma_levels(captures), chroma_levels(cleans)
    if real <= MONOCHROME_LEVELS and clean >= MONOCHROME_CONTRAST * max(real, 0.25):
        return {"chroma_levels": round(real, 3), "clean_chroma_levels": round(clean, 3)}
    return None


def monochrome_color() -> Color:
    """The colour stage of a monochrome camera: every channel the BT.601 luma of the sRGB values."""
    return Color(torch.tensor([BT601_LUMA] * 3), linear=False)


def _curve(tone: Tone, values: Tensor) -> Tensor:
    return tone_curve(values, *(getattr(tone, key).double() for key in ("gamma", "black", "white", "exposure")))
