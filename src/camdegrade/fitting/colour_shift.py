"""A colour shift the camera makes, kept when a fit drops its network.

A network that gains less than ``NETWORK_MIN_GAIN_DB`` over the clean image is dropped, and the profile keeps its
effect stages only. A shift between the channels can be smaller than the noise in every pixel (red ×1.025 and blue
×0.975 under 12 levels of noise: the network gained 0.11 dB) and still be the camera's on every capture: its mean
over the pairs stands out of the pairs' spread. Each channel's log ratio of the capture's mean to the clean image's
(over pixels of mid values in the clean image, averaged per scene) is tested against its standard error over the
scenes; where some channel's is beyond :data:`SIGNIFICANCE` standard errors and :data:`MIN_SHIFT`, a
:class:`~camdegrade.effects.Color` stage of per-channel gains (white balance, in linear light) is fitted and kept.
On the real pairs: PolyU (30 scenes) and CC15 (5) show none, SIDD's 12 captures are darker than their references by
3.4–7.2 % (blue most), beyond 3 standard errors (docs/results.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import torch
from torch import Tensor

from camdegrade.effects import Color

__all__ = ["MIN_SCENES", "MIN_SHIFT", "SIGNIFICANCE", "channel_shift", "colour_shift"]

#: A channel's mean log ratio counts when it is beyond this many standard errors over the scenes ...
SIGNIFICANCE = 3.0
#: ... and at least this large (0.5 %: under one 8-bit level at mid-grey).
MIN_SHIFT = 0.005
#: ... over at least this many scenes (a standard error of fewer says little).
MIN_SCENES = 3
#: Pixels whose every channel lies inside this range in the clean image are averaged: away from 0 and 1, where the
#: capture's noise is clipped and its mean biased (selecting by the capture's own values would bias it too).
UNSATURATED = (0.15, 0.85)

ImagePair = tuple[Tensor, Tensor]


def channel_shift(pairs: Sequence[ImagePair], scenes: Sequence[str]) -> tuple[Tensor, Tensor, int]:
    """Per channel, the mean over scenes of ``log(mean captured / mean clean)`` over the pixels whose clean values
    lie in :data:`UNSATURATED` (each scene the mean of its pairs), its standard error over the scenes (NaN with one
    scene), and the number of scenes."""
    by_scene: dict[str, list[Tensor]] = {}
    low, high = UNSATURATED
    for (clean, captured), scene in zip(pairs, scenes, strict=True):
        clean, captured = clean.double().reshape(3, -1), captured.double().reshape(3, -1)
        usable = ((clean > low) & (clean < high)).all(0)
        if int(usable.sum()) < 16:
            continue
        ratio = captured[:, usable].mean(1) / clean[:, usable].mean(1)
        by_scene.setdefault(scene, []).append(ratio.log())
    if not by_scene:
        return torch.full((3,), math.nan), torch.full((3,), math.nan), 0
    per_scene = torch.stack([torch.stack(values).mean(0) for values in by_scene.values()])
    count = per_scene.shape[0]
    error = per_scene.std(0) / math.sqrt(count) if count > 1 else torch.full((3,), math.nan, dtype=torch.float64)
    return per_scene.mean(0), error, count


def colour_shift(
    train: Sequence[ImagePair], pairs: Sequence[ImagePair], scenes: Sequence[str], say: Callable[[str], None]
) -> tuple[Color | None, dict[str, Any]]:
    """A colour stage of per-channel gains fitted on ``train`` where ``pairs`` of ``scenes`` (every pair of the fit)
    show a significant shift (:func:`channel_shift`), or ``None``; and its record (``fitted['effects']['color']``)."""
    shift, error, count = channel_shift(pairs, scenes)
    standing = (shift.abs() > SIGNIFICANCE * error) & (shift.abs() >= MIN_SHIFT) & (count >= MIN_SCENES)
    note: dict[str, Any] = {
        "log_ratio": [round(float(value), 4) for value in shift],
        "standard_error": [round(float(value), 5) if math.isfinite(value) else None for value in error.tolist()],
        "scenes": count,
        "significance": SIGNIFICANCE,
        "min_shift": MIN_SHIFT,
    }
    shown = ", ".join(f"{name} {float(value):+.3f}" for name, value in zip("RGB", shift, strict=True))
    if not bool(standing.any()):
        say(f"colour shift: none significant ({shown} log ratio over {count} scene(s))")
        return None, {**note, "kept": False}
    colour = Color.fit([clean for clean, _ in train], [captured for _, captured in train], diagonal=True)
    gains = [round(float(value), 4) for value in colour.matrix.diagonal()]
    say(
        f"colour shift: {shown} log ratio over {count} scenes, beyond {SIGNIFICANCE:g} standard errors: a colour "
        f"stage of gains {gains} is kept without the network"
    )
    return colour, {**note, "kept": True, "gains": gains}
