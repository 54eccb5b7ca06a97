"""A JPEG stage that draws each sample's quality from a set of qualities with their weights (issue 44: captures
saved at qualities 30 and 95 were modelled as one quality 95): the draws follow the weights, a profile stores and
reloads the mixture, and a bad mixture is refused by the class and by the file check alike."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from safetensors import safe_open
from safetensors.torch import load_file, save_file

from camdegrade import CameraProfile, load_profile
from camdegrade.__main__ import main
from camdegrade.effects import JPEG
from camdegrade.errors import ProfileError


def _drawn(stage: JPEG, count: int, seed: int = 0) -> list[int]:
    params = stage.make_params((count, 3, 8, 8), torch.Generator().manual_seed(seed))
    return (stage.quality + params["quality_offset"]).long().tolist()


def test_the_draws_follow_the_weights_and_replay() -> None:
    stage = JPEG(95, mixture={30: 1, 95: 3})
    assert stage.mixture == {30: 0.25, 95: 0.75}
    drawn = _drawn(stage, 2000)
    assert set(drawn) == {30, 95} and 0.22 <= drawn.count(30) / 2000 <= 0.28
    assert _drawn(stage, 2000) == drawn  # the same seed, the same qualities
    image = torch.rand(2, 3, 16, 16, generator=torch.Generator().manual_seed(1))
    params = {"quality_offset": torch.tensor([30 - 95, 0])}
    torch.testing.assert_close(stage(image, params)[0], JPEG(30)(image[:1])[0], atol=0, rtol=0)
    assert stage.without_randomness().mixture == {} and int(stage.without_randomness().quality) == 95
    assert stage.scaled(0.5).mixture_qualities.tolist() == [65.0, 98.0]  # halfway to 100, rounded


def test_a_profile_keeps_the_mixture(tmp_path: Path) -> None:
    path = CameraProfile(None, [JPEG(75, mixture={50: 0.5, 75: 0.3, 90: 0.2})]).save(tmp_path / "mix.safetensors")
    stage = load_profile(path).effects[0]
    assert isinstance(stage, JPEG) and stage.config()["mixture"] == 3
    assert stage.mixture == pytest.approx({50: 0.5, 75: 0.3, 90: 0.2})


@pytest.mark.parametrize(
    ("mixture", "message"),
    [
        ({0: 1.0}, r"mixture qualities must be integers from 1 to 100, got 0"),
        ({50.5: 1.0}, r"mixture qualities must be integers from 1 to 100, got 50.5"),
        ({50: -1.0}, r"mixture weights must be finite and non-negative, got -1.0 for quality 50"),
        ({50: float("nan")}, r"mixture weights must be finite and non-negative, got nan"),
        ({50: 0.0, 60: 0.0}, r"mixture weights must not all be 0"),
    ],
)
def test_a_bad_mixture_is_refused_by_name(mixture: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        JPEG(50, mixture=mixture)


def test_a_file_whose_weights_do_not_sum_to_one_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = CameraProfile(None, [JPEG(75, mixture={50: 0.5, 90: 0.5})]).save(tmp_path / "mix.safetensors")
    with safe_open(str(path), "pt") as opened:
        metadata = opened.metadata()
    tensors = load_file(str(path))
    key = next(name for name in tensors if name.endswith("mixture_weights"))
    tensors[key] = torch.tensor([0.5, 0.6])
    save_file(tensors, str(path), metadata=metadata)
    with pytest.raises(ProfileError, match=r"effect 0 \(jpeg\): mixture_weights must sum to 1, got a sum of 1\.1"):
        load_profile(path)
    assert main(["info", str(path)]) == 1  # the torch-free check refuses it too
    assert "mixture_weights must sum to 1, got a sum of 1.1" in capsys.readouterr().err
