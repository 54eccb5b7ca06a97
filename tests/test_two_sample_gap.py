"""The learned stage's spectrum term held at the captures' set gap (``TwoSampleOptions.spectrum_target="captures"``,
issue 43): the gap cancels the two sets' contrast, and the stage trained with it moves its output's band power
toward the captures' where the default keeps its input's."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch
from torch import Tensor

from camdegrade.fitting.two_sample.train import TwoSampleOptions, fit_two_sample, spectrum_gap
from camdegrade.measures.fidelity import band_power
from effects_images import grainy, smooth_scenes

torch.set_num_threads(1)
SMALL = TwoSampleOptions(patch=32, batch=4, width=4, critic_width=4)


def test_the_gap_is_zero_for_the_same_images_and_for_a_contrast_change_alone() -> None:
    images = grainy(smooth_scenes(3, 0), 4.0, 1)
    assert torch.equal(spectrum_gap(images, images), torch.zeros(5))
    halved = [(image - image.mean()) * 0.5 + image.mean() for image in images]  # power / 4 in every band
    assert float(spectrum_gap(images, halved).abs().max()) < 1e-4


def test_the_gap_is_the_grain_the_captures_have_above_the_lowest_band() -> None:
    gap = spectrum_gap(smooth_scenes(3, 0), grainy(smooth_scenes(3, 1), 8.0, 2))
    assert gap[0] == 0.0
    assert bool((gap[1:] > 4.0).all()) and bool((gap[1:].diff() > 0).all()), gap  # white grain over smooth scenes


def _output_gap(target: str) -> Tensor:
    """The band log2 power of the stage's output over its input's, trained 20 steps against grainy captures."""
    cleans, captures = smooth_scenes(3, 0), grainy(smooth_scenes(3, 1), 8.0, 2)
    options = replace(SMALL, spectrum_target=target, spectrum_weight=20.0)
    stage, evidence = fit_two_sample(lambda images: list(images), cleans, captures, seed=0, steps=20, options=options)
    assert evidence["options"]["spectrum_target"] == target
    inputs = torch.stack(cleans)
    outputs = stage(inputs, stage.make_params(tuple(inputs.shape), torch.Generator().manual_seed(0)))
    return band_power(outputs).log2().mean(0) - band_power(inputs).log2().mean(0)


@pytest.mark.slow  # two trainings of 20 steps
def test_the_captures_target_moves_the_output_toward_the_captures_band_power() -> None:
    kept, moved = _output_gap("input"), _output_gap("captures")
    assert bool((moved[2:] - kept[2:] > 4.0).all()), (kept, moved)  # 20 steps: 8.5–13.9 log2 against 0.1–3.2
    assert abs(float(moved[0])) < 0.1 and abs(float(kept[0])) < 0.1, (kept, moved)  # low band left alone


def test_an_unknown_target_is_refused_by_name() -> None:
    with pytest.raises(ValueError, match=r"spectrum_target must be one of \('input', 'captures'\), got 'real'"):
        fit_two_sample(
            lambda images: list(images),
            smooth_scenes(2, 0),
            smooth_scenes(2, 1),
            steps=1,
            options=replace(SMALL, spectrum_target="real"),
        )
