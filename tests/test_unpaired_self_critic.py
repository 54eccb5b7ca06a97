"""The unpaired fit's self-check critic (issue 43, item 2): a fresh image-only critic, trained on half of the images
and scored on the other half, tells the clean set simulated through the fitted chain from the captures; above
:data:`~camdegrade.fitting.critic_warning.CRITIC_WARNING_ACCURACY` the fit warns with the numbers and ``strict``
refuses. The cameras are generated (dead-leaves scenes with grey cards, tests/test_unpaired_fit.py's); the clean set
shows other scenes."""

from __future__ import annotations

import pytest
import torch

from camdegrade._profile_format.summary import quality_lines
from camdegrade.effects import Noise, Tone
from camdegrade.errors import CamdegradeError
from camdegrade.fitting.critic_warning import CRITIC_WARNING_ACCURACY
from camdegrade.fitting.unpaired import fit_unpaired, judges
from camdegrade.fitting.unpaired.judges import self_check_critic
from test_unpaired_fit import _captures, _scenes

NOISY = Noise(levels=torch.full((3, 4), 6.0 / 255), linear=False)
GRAINY = Noise(levels=torch.full((3, 4), 16.0 / 255), linear=False)


def _critic_warnings(profile) -> list[str]:
    return [text for text in profile.fitted.get("warnings", []) if "fresh image-only critic" in text]


@pytest.mark.slow
@pytest.mark.usefixtures("unpaired_critic")
def test_a_camera_the_stages_reproduce_reads_near_chance_and_is_not_warned_about() -> None:
    profile = fit_unpaired(_captures(Tone(gamma=1.3), NOISY), _scenes(1))
    critic = profile.quality["unpaired_fidelity"]["critic_image_only"]
    assert critic["critics"] == 2 and critic["pairs"] == 16, critic
    assert critic["accuracy"] <= CRITIC_WARNING_ACCURACY, critic
    print("reproduced camera:", critic)
    assert _critic_warnings(profile) == []


@pytest.mark.slow
@pytest.mark.usefixtures("unpaired_critic")
def test_a_camera_the_stages_cannot_reproduce_is_warned_about_with_its_numbers_and_strict_refuses() -> None:
    captures, clean = _captures(Tone(gamma=1.3), GRAINY), _scenes(1)
    profile = fit_unpaired(captures, clean, effects=("tone",))  # the camera's noise is left out of the fit
    critic = profile.quality["unpaired_fidelity"]["critic_image_only"]
    assert critic["accuracy"] > CRITIC_WARNING_ACCURACY, critic
    print("camera with its noise left out:", critic)
    (warning,) = _critic_warnings(profile)
    assert f"{critic['accuracy']:.2f} [{critic['low']:.2f}–{critic['high']:.2f}]" in warning
    with pytest.raises(CamdegradeError, match="fresh image-only critic"):
        fit_unpaired(captures, clean, effects=("tone",), strict=True)


@pytest.mark.slow
@pytest.mark.usefixtures("unpaired_critic")
def test_without_a_clean_set_the_critic_is_not_measured() -> None:
    profile = fit_unpaired(_captures(Tone(gamma=1.3)), effects=("tone",))
    assert profile.quality["unpaired_fidelity"]["critic_image_only"] is None


def test_too_few_images_of_a_critics_patch_are_not_measured() -> None:
    small = [torch.rand(3, 24, 24)] * 8  # under a critic's 32-pixel patch
    assert self_check_critic(lambda images: images, small, small) is None


@pytest.mark.usefixtures("unpaired_critic")
def test_too_few_images_are_not_measured() -> None:
    few = [torch.rand(3, 64, 64) for _ in range(judges.MIN_CRITIC_IMAGES - 1)]
    assert self_check_critic(lambda images: images, few, few) is None


def test_the_summary_says_the_unpaired_critic_and_a_stray_value_as_not_a_number() -> None:
    record = {"bands": [0.1, -0.2], "noise_ratio": 1.02, "spectrum_mismatch": 0.01}
    text = " ".join(quality_lines({"unpaired_fidelity": {**record, "critic_image_only": {"accuracy": 0.61}}}))
    assert "image-only critic 0.61" in text
    text = " ".join(quality_lines({"unpaired_fidelity": {**record, "critic_image_only": [1, 2]}}))
    assert "image-only critic n/a" in text
