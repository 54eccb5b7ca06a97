"""A short fine-tune of a profile's network on (clean, captured) pairs, through the profile's deterministic stages.

The diagnosis uses it to test whether a gap that no effect explains (8×8 block energy from the stride-2 transposed
convolutions, a high-frequency transfer the network gets wrong) is the network's own: the network is trained a
little more on the calibration pairs, with the effect stages after it in the loss, and the held-out gap is measured
again. For a full refit, ``camdegrade fit PAIRS -o NEW.safetensors --init-from PROFILE`` starts from the profile's
weights.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade.network import ShiftNetwork
from camdegrade.profile import CameraProfile

__all__ = ["LEARNING_RATE", "PIXELS", "STEPS", "finetune_network"]

#: Full-batch Adam steps on the decoder, over calibration pairs of about ``PIXELS`` pixels in all.
STEPS = 40
PIXELS = 1 << 19
LEARNING_RATE = 3e-4


def finetune_network(
    profile: CameraProfile,
    cleans: Sequence[Tensor],
    captures: Sequence[Tensor],
    *,
    steps: int = STEPS,
    pixels: int = PIXELS,
) -> ShiftNetwork:
    """A copy of ``profile.network`` whose decoder is trained ``steps`` full-batch Adam steps (L2) so that the
    profile's deterministic output matches ``captures`` (float ``(3, H, W)`` in [0, 1]) on evenly chosen pairs of
    about ``pixels`` pixels in all.

    The decoder alone (the paper's two transposed convolutions, where block and checkerboard patterns come from;
    a :class:`~camdegrade.network.LocalAffineNet`'s colour-field convolutions and full-resolution filter), and the
    whole batch at every step: a few pairs' noise would otherwise steer small crops, and the fine-tune would fit the
    noise of the calibration captures rather than the network's error.

    Raises:
        ValueError: the profile has no network, or a stage after it passes no gradient (JPEG).
    """
    if profile.network is None:
        raise ValueError("the profile has no network to fine-tune")
    chosen = _evenly(list(zip(cleans, captures, strict=True)), pixels)
    tuned = copy.deepcopy(profile.without_randomness())
    network = tuned.network
    assert network is not None  # a copy of a profile with a network
    decoder = [parameter for name, parameter in network.named_parameters() if not name.startswith("encode")]
    for parameter in decoder:
        parameter.requires_grad_(True)
    optimizer = torch.optim.Adam(decoder, lr=LEARNING_RATE)
    network.encode = _FrozenFeatures(network.encode)  # type: ignore[method-assign]  # the copy's own, dropped below
    network.to(memory_format=torch.channels_last)  # its convolutions' gradients several times faster on the CPU
    with torch.enable_grad():
        for _ in range(steps):
            loss = torch.zeros(())
            for clean, capture in chosen:  # one pair at a time: sizes may differ
                output = tuned(clean[None], tuned.make_params((1, *clean.shape), torch.Generator()))
                if not output.requires_grad:
                    raise ValueError("a stage after the network passes no gradient (e.g. jpeg); cannot fine-tune it")
                loss = loss + F.mse_loss(output[0], capture, reduction="sum")
            optimizer.zero_grad(set_to_none=True)
            (loss / sum(capture.numel() for _, capture in chosen)).backward()
            optimizer.step()
    del network.encode  # back to the class's method
    network.to(memory_format=torch.contiguous_format)
    return network.requires_grad_(False).eval()


class _FrozenFeatures:
    """The frozen encoder's features of each input, computed at the first step and reused at every later one: only
    the decoder is trained, so the features of an input never change (the same bytes as computing them again)."""

    def __init__(self, encode: Callable[[Tensor], Tensor]) -> None:
        self.encode = encode
        self.seen: list[tuple[Tensor, Tensor]] = []

    def __call__(self, image: Tensor) -> Tensor:
        for known, features in self.seen:
            if known.shape == image.shape and torch.equal(known, image):
                return features
        with torch.no_grad():
            features = self.encode(image)
        self.seen.append((image.detach().clone(), features))
        return features


def _evenly(pairs: list[tuple[Tensor, Tensor]], pixels: int) -> list[tuple[Tensor, Tensor]]:
    """Evenly spaced pairs holding about ``pixels`` pixels (at least one pair)."""
    per_pair = sum(clean.shape[-1] * clean.shape[-2] for clean, _ in pairs) / len(pairs)
    count = max(1, min(len(pairs), round(pixels / per_pair)))
    step = len(pairs) / count
    return [pairs[int(index * step)] for index in range(count)]
