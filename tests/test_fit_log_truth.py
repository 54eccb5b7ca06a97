"""What a fit's log says it does is what it does (issue 44): an unpaired fit, which has no network, never says that
one is trained through the upscale it finds; a paired fit still does."""

from __future__ import annotations

import numpy as np
import torch
from PIL import Image

from camdegrade.fitting.steps.resolution import sensor_trace, sensor_verdict
from camdegrade.fitting.unpaired import fit_unpaired
from camdegrade.fitting.unpaired.images import MIN_IMAGES
from camdegrade.synthetic import dead_leaves_images

torch.set_num_threads(1)


def _upscaled_by_pil(count: int, seed: int) -> list[torch.Tensor]:
    """Dead-leaves scenes of 64² upscaled 2× by PIL's bicubic filter (a resampler that is not ours)."""
    out = []
    for image in dead_leaves_images(count, 64, seed=seed):
        picture = Image.fromarray(image.permute(1, 2, 0).numpy()).resize((128, 128), Image.BICUBIC)
        out.append(torch.from_numpy(np.asarray(picture).copy()).permute(2, 0, 1))
    return out


def test_the_unpaired_fit_says_what_it_does_with_an_upscale_it_finds() -> None:
    lines: list[str] = []
    profile = fit_unpaired(_upscaled_by_pil(MIN_IMAGES, seed=3), effects=("resolution",), log=lines.append)
    assert profile.network is None and profile.effect_names == ["resolution"]
    found = [line for line in lines if line.startswith("resolution: the captures are upscaled from 1/2")]
    assert len(found) == 1, lines
    assert "trained" not in found[0], found[0]
    assert found[0].endswith("): every later stage is fitted through it (the profile has no network)"), found[0]


def test_the_sensor_verdict_ends_its_line_with_what_the_caller_does() -> None:
    lines: list[str] = []
    trace = sensor_trace(None, _upscaled_by_pil(MIN_IMAGES, seed=4))
    stage, note = sensor_verdict(trace, lines.append, then="CALLER'S WORDS")
    assert stage is not None and note["kept"] is True and lines[-1].endswith("): CALLER'S WORDS"), lines
