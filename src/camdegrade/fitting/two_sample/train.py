"""``fit_two_sample``: a :class:`~camdegrade.effects.LearnedTexture` stage trained, after a profile's named stages,
so that its output's texture cannot be told from the camera's own photos by a critic, while keeping the low
frequencies of what it was given.

The game, on random patches (a few hundred to a few thousand fixed steps, seeded):

- the critic (:class:`~camdegrade.fitting.two_sample.critic.PatchCritic`, spectral norm, high frequencies only) learns
  to tell the camera's patches from the stage's output with a hinge loss;
- the stage learns to fool it (``−critic``), held by a content term, the L1 distance between its output's low-pass
  and its input's (frequency separation: what the named stages fitted is kept, the texture is free), a spectrum
  term that keeps the batch's power in each band of the spectrum (the named stages matched the captures' set
  spectrum; without it the stage learned to smooth edges and left the top band 0.7–1.3 log2 short on City100's
  held-out scenes, docs/results.md; with ``spectrum_target="captures"``, as the unpaired fit's step trains, the
  batch's power over its input's held at the captures' set gap instead), and, for aligned pairs, an L2 term
  against the capture (``pixel_weight``: pix2pix's L1 + GAN, in squares). The stage itself cannot move its input's
  low frequencies (:class:`~camdegrade.effects.LearnedTexture` takes them out of its residual).

Outputs are rounded to 8-bit values in the forward pass (the gradient passes straight through): the captures are
8-bit, and a critic could tell continuous values from them. The stage returned is an exponential moving average of
the trained one's weights. With ``checkpoint`` the whole state (stage, average, critic, both optimizers, the sampler's
generator) is written every ``checkpoint_every`` steps as safetensors; ``resume=True`` continues from it to the same
bytes as an uninterrupted run.

References:
    M. Fritsche, S. Gu, R. Timofte, "Frequency Separation for Real-World Super-Resolution", ICCV Workshops 2019.
    J. H. Lim, J. C. Ye, "Geometric GAN" (the hinge loss), 2017.
    P. Isola, J.-Y. Zhu, T. Zhou, A. A. Efros, "Image-to-Image Translation with Conditional Adversarial Networks",
    CVPR 2017.
"""

from __future__ import annotations

import copy
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor
from tqdm.auto import tqdm

from camdegrade._support.files import check_writable
from camdegrade._support.seeds import derive_seed, derived_generator
from camdegrade.effects import LearnedTexture
from camdegrade.errors import FitInterrupted
from camdegrade.fitting.network.checkpoint import pairs_fingerprint
from camdegrade.fitting.two_sample.critic import PatchCritic, low_pass
from camdegrade.fitting.two_sample.state import TwoSampleState, load_state, save_state
from camdegrade.measures.fidelity import BAND_EDGES, band_power
from camdegrade.profile import CameraProfile

__all__ = ["SPECTRUM_TARGETS", "TwoSampleOptions", "fit_two_sample", "spectrum_gap"]

Simulator = Callable[[Sequence[Tensor]], list[Tensor]]


@dataclass(frozen=True)
class TwoSampleOptions:
    """How the stage is trained (every field is recorded in the evidence and must match on resume).

    Attributes:
        patch, batch: patch side (pixels) and patches per side per step.
        width: the stage's hidden channels; noise: whether it draws a noise plane.
        critic_width: the critic's first layer's channels; high_only: the critic sees the high-pass only.
        sigma: the Gaussian low-pass (pixels) that splits content from texture.
        content_weight: weight of the low-pass L1 term; pixel_weight: of the L2 term against aligned captures.
        spectrum_weight: weight of the spectrum term: the mean squared log2 difference of the batch's luma power
            in the five bands of :data:`~camdegrade.measures.fidelity.BAND_EDGES`, output against input, less
            the set gap of ``spectrum_target``.
        spectrum_target: ``"input"``: the output keeps its input's band power (gap 0); ``"captures"``: the
            output's band power over its input's (a ratio on the same patches: their content cancels) is held at
            the captures' set gap (:func:`spectrum_gap`), the statistic the gate judges.
        learning_rate, critic_learning_rate: Adam's, constant for the first half, then down linearly to 0.
        average: decay of the weights' moving average (the stage returned).
    """

    patch: int = 64
    batch: int = 8
    width: int = 8
    noise: bool = True
    critic_width: int = 16
    high_only: bool = True
    sigma: float = 1.5
    content_weight: float = 20.0
    spectrum_weight: float = 2.0
    spectrum_target: str = "input"
    pixel_weight: float = 0.0
    learning_rate: float = 2e-3
    critic_learning_rate: float = 2e-3
    average: float = 0.99


#: What the spectrum term holds the output's band power to (:class:`TwoSampleOptions`).
SPECTRUM_TARGETS = ("input", "captures")
BANDS = len(BAND_EDGES) - 1
#: Steps between two entries of the evidence's loss history.
HISTORY_EVERY = 25


def fit_two_sample(
    named: CameraProfile | Simulator,
    cleans: Sequence[Tensor],
    captures: Sequence[Tensor],
    *,
    seed: int = 0,
    steps: int = 1200,
    options: TwoSampleOptions | None = None,
    paired: bool = False,
    checkpoint: str | os.PathLike[str] | None = None,
    checkpoint_every: int = 100,
    resume: bool = False,
    progress: bool = False,
    callback: Callable[[int, dict[str, float]], None] | None = None,
) -> tuple[LearnedTexture, dict[str, Any]]:
    """Train a :class:`~camdegrade.effects.LearnedTexture` after the named stages against ``captures``.

    Args:
        named: the profile of the named stages (simulated with ``seed``, stored as 8-bit values) or a function
            ``cleans → images`` that simulates them.
        cleans, captures: ``(3, H, W)`` float images in [0, 1], at least ``options.patch`` pixels a side; with
            ``paired``, ``captures[i]`` is aligned with ``cleans[i]`` (the L2 term's target).
        seed: patches, noise and initial weights; same seed, same bytes.
        steps: training steps (the schedule is laid over them).
        checkpoint, checkpoint_every, resume: see the module.
        callback: called as ``callback(step, losses)`` after each step (a KeyboardInterrupt from it, or from the
            user, ends the fit with :class:`~camdegrade.fitting.FitInterrupted`, the last checkpoint kept).

    Returns:
        The stage and its evidence: options, steps, seconds, the loss history.
    """
    options = options or TwoSampleOptions()
    if options.spectrum_target not in SPECTRUM_TARGETS:
        raise ValueError(f"spectrum_target must be one of {SPECTRUM_TARGETS}, got {options.spectrum_target!r}")
    inputs = _named_outputs(named, cleans, seed)
    sampler = _Sampler(inputs, list(captures), options.patch, options.batch, paired)
    if checkpoint is not None:
        check_writable(checkpoint)
    fingerprint = pairs_fingerprint([(image,) for image in inputs], [(image,) for image in captures])
    gap = spectrum_gap(inputs, list(captures)) if options.spectrum_target == "captures" else torch.zeros(BANDS)
    game = _Game(options, steps, seed, sampler, gap)
    state = game.resumed(checkpoint, fingerprint) if resume else None
    started = time.perf_counter()
    bar = tqdm(total=steps, initial=game.step, desc="learned texture", unit="step", disable=not progress)
    try:
        while game.step < steps:
            losses = game.play()
            bar.update(1)
            if game.step % HISTORY_EVERY == 0:
                bar.set_postfix({key: f"{value:.3f}" for key, value in losses.items()})
            if checkpoint is not None and (game.step % checkpoint_every == 0 or game.step == steps):
                save_state(game.state(fingerprint), checkpoint)
            if callback is not None:
                callback(game.step, losses)
    except KeyboardInterrupt:
        where = f"; resume with the same checkpoint ({checkpoint})" if checkpoint else ""
        raise FitInterrupted(f"two-sample fit interrupted at step {game.step} of {steps}{where}") from None
    finally:
        bar.close()
    evidence = {
        "options": asdict(options),
        "steps": steps,
        "paired": paired,
        "seed": seed,
        "resumed_at": state.step if state is not None else None,
        "seconds": round(time.perf_counter() - started, 1),
        "spectrum_gap": [round(float(value), 4) for value in gap],
        "history": game.history,
    }
    return game.result(), evidence


def _named_outputs(named: CameraProfile | Simulator, cleans: Sequence[Tensor], seed: int) -> list[Tensor]:
    """The named stages' output on ``cleans``, stored as 8-bit values (as the captures are)."""
    images = named.simulate(list(cleans), seed, stream="two-sample") if isinstance(named, CameraProfile) else None
    images = images if images is not None else list(named(list(cleans)))
    if len(images) != len(cleans):
        raise ValueError(f"named must give one image per clean image ({len(cleans)}), got {len(images)}")
    return [image.detach().float().clamp(0, 1).mul(255).round().div(255) for image in images]


class _Sampler:
    """Random patches: of the named stages' outputs, of the captures (at the same place of the same image when
    ``paired``)."""

    def __init__(self, inputs: list[Tensor], captures: list[Tensor], patch: int, batch: int, paired: bool) -> None:
        for label, images in (("cleans", inputs), ("captures", captures)):
            if not images or any(min(image.shape[-2:]) < patch for image in images):
                raise ValueError(f"{label} must be non-empty images of at least {patch}x{patch} pixels")
        if paired and [image.shape for image in inputs] != [image.shape for image in captures]:
            raise ValueError("paired: captures must be aligned with cleans (one each, the same sizes)")
        self.inputs, self.captures, self.patch, self.batch, self.paired = inputs, captures, patch, batch, paired

    def draw(self, generator: torch.Generator) -> tuple[Tensor, Tensor, Tensor]:
        """``(inputs, captures, noise)`` of one step: ``(batch, 3, patch, patch)`` twice and the noise plane."""
        fakes = self._crops(self.inputs, generator)
        places = fakes[1] if self.paired else None
        reals = self._crops(self.captures, generator, places)
        noise = torch.randn(self.batch, 1, self.patch, self.patch, generator=generator)
        return fakes[0], reals[0], noise

    def _crops(self, images: list[Tensor], generator: torch.Generator, places: list | None = None) -> tuple:
        if places is None:
            places = []
            for index in torch.randint(0, len(images), (self.batch,), generator=generator).tolist():
                height, width = images[index].shape[-2:]
                top = int(torch.randint(0, height - self.patch + 1, (1,), generator=generator))
                left = int(torch.randint(0, width - self.patch + 1, (1,), generator=generator))
                places.append((index, top, left))
        crops = [images[i][:, y : y + self.patch, x : x + self.patch] for i, y, x in places]
        return torch.stack(crops), places


def _rounded(image: Tensor) -> Tensor:
    """``image`` at 8-bit values in the forward pass, its gradient passed straight through."""
    return image + (image.mul(255).round().div(255) - image).detach()


def _band_log2(patches: Tensor) -> Tensor:
    """``(5,)`` log2 of the batch's mean luma power per band (:func:`~camdegrade.measures.fidelity.band_power`)."""
    return band_power(patches).mean(0).clamp_min(1e-8).log2()


def spectrum_gap(inputs: Sequence[Tensor], captures: Sequence[Tensor]) -> Tensor:
    """``(5,)`` the captures' set mean of log2 band power (:func:`~camdegrade.measures.fidelity.band_power` of
    each image whole; the gate reads centre crops) less the inputs', less that difference in the lowest band: the
    contrast of the two sets' scenes, which the stage cannot move (its residual's low-pass is taken out) and must
    not be asked to."""

    def mean_log2(images: Sequence[Tensor]) -> Tensor:
        powers = [band_power(image.float())[0] for image in images]
        return torch.stack(powers).clamp_min(1e-8).log2().mean(0)

    gap = mean_log2(captures) - mean_log2(inputs)
    return (gap - gap[0]).float()


def _schedule(step: int, steps: int) -> float:
    """The learning rates' factor: 1 for the first half of the steps, then down linearly to 0."""
    return min(1.0, 2.0 * (1.0 - step / steps))


class _Game:
    """The stage, its moving average, the critic, their optimizers and the sampler's generator: one step at a
    time."""

    def __init__(self, options: TwoSampleOptions, steps: int, seed: int, sampler: _Sampler, gap: Tensor) -> None:
        self.options, self.steps, self.seed, self.sampler, self.gap = options, steps, seed, sampler, gap
        self.stage = LearnedTexture.initial(options.width, derive_seed(seed, "two-sample-stage") % 2**63)
        self.stage.noise, self.stage.sigma = options.noise, options.sigma
        for buffer in self.stage.buffers():
            buffer.requires_grad_(True)
        self.average = copy.deepcopy(self.stage).requires_grad_(False)
        for buffer in self.average.buffers():
            buffer.requires_grad_(False)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(derive_seed(seed, "two-sample-critic"))
            self.critic = PatchCritic(options.critic_width, high_only=options.high_only)
        self.generator = derived_generator(seed, "two-sample-patches")
        self.critic.standardise(sampler.draw(derived_generator(seed, "two-sample-scale"))[1], options.sigma)
        betas = (0.5, 0.99)
        self.stage_optimizer = torch.optim.Adam(list(self.stage.buffers()), lr=options.learning_rate, betas=betas)
        self.critic_optimizer = torch.optim.Adam(self.critic.parameters(), lr=options.critic_learning_rate, betas=betas)
        self.step = 0
        self.history: list[dict[str, float]] = []

    def play(self) -> dict[str, float]:
        """One step: the critic on this batch, then the stage against the updated critic."""
        options = self.options
        for optimizer, rate in (
            (self.stage_optimizer, options.learning_rate),
            (self.critic_optimizer, options.critic_learning_rate),
        ):
            for group in optimizer.param_groups:
                group["lr"] = rate * _schedule(self.step, self.steps)
        inputs, reals, noise = self.sampler.draw(self.generator)
        fakes = _rounded(self.stage(inputs, {"noise": noise}))
        real_logits = self.critic(self.critic.planes(reals, options.sigma))
        fake_logits = self.critic(self.critic.planes(fakes.detach(), options.sigma))
        critic_loss = F.relu(1 - real_logits).mean() + F.relu(1 + fake_logits).mean()
        self.critic_optimizer.zero_grad(set_to_none=True)
        critic_loss.backward()
        self.critic_optimizer.step()
        adversarial = -self.critic(self.critic.planes(fakes, options.sigma)).mean()
        content = (low_pass(fakes, options.sigma) - low_pass(inputs, options.sigma)).abs().mean()
        spectrum = (_band_log2(fakes) - _band_log2(inputs) - self.gap).pow(2).mean()
        loss = adversarial + options.content_weight * content + options.spectrum_weight * spectrum
        pixel = (fakes - reals).pow(2).mean() if self.sampler.paired else torch.zeros(())
        loss = loss + options.pixel_weight * pixel
        self.stage_optimizer.zero_grad(set_to_none=True)
        self.critic.requires_grad_(False)
        loss.backward()
        self.critic.requires_grad_(True)
        self.stage_optimizer.step()
        self._average()
        self.step += 1
        losses = {
            "critic": critic_loss.item(),
            "adversarial": adversarial.item(),
            "content": content.item(),
            "spectrum": spectrum.item(),
            "pixel": pixel.item(),
        }
        if self.step % HISTORY_EVERY == 0:
            self.history.append({"step": self.step, **{key: round(value, 5) for key, value in losses.items()}})
        return losses

    def _average(self) -> None:
        decay = self.options.average
        with torch.no_grad():
            for mean, value in zip(self.average.buffers(), self.stage.buffers(), strict=True):
                mean.mul_(decay).add_(value, alpha=1 - decay)

    def result(self) -> LearnedTexture:
        """The averaged stage, detached, checked."""
        weights = dict(self.average.named_buffers())
        out = LearnedTexture(self.options.width, noise=self.options.noise, sigma=self.options.sigma, weights=weights)
        out.check_values()
        return out

    def state(self, fingerprint: str) -> TwoSampleState:
        return TwoSampleState.capture(self, fingerprint)

    def resumed(self, checkpoint: str | os.PathLike[str] | None, fingerprint: str) -> TwoSampleState:
        """This game set to the state in ``checkpoint`` (which must match its options, seed, steps and data)."""
        if checkpoint is None:
            raise ValueError("resume=True needs checkpoint=PATH")
        state = load_state(checkpoint)
        state.check_matches(self, fingerprint, checkpoint)
        state.restore(self)
        return state
