"""Fast profiles: generated dead-leaves images, distilling a profile's network into a narrower one, the CLI."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from camdegrade import CameraProfile, load_profile
from camdegrade.cli import main
from camdegrade.effects import Blur, Tone
from camdegrade.fitting.network.distill import distill_profile
from camdegrade.fitting.recipe import FitConfig
from camdegrade.io import write_image
from camdegrade.synthetic import dead_leaves_image, dead_leaves_images
from profiles_for_tests import seeded_network

TINY = FitConfig(epochs=2, crop=32, batch_size=4, crops_per_pair=2, patience=0)


def _teacher() -> CameraProfile:
    return CameraProfile(seeded_network(1), [Blur(0.8), Tone(gamma=1.1)], name="teacher", description="a test camera")


def test_dead_leaves_repeat_from_their_seed_and_hold_flat_areas_and_edges() -> None:
    first, second = dead_leaves_images(3, 64, seed=5), dead_leaves_images(2, 64, seed=5)
    assert all(torch.equal(a, b) for a, b in zip(first, second))  # image i does not depend on the count
    assert not torch.equal(first[0], first[1])
    assert not torch.equal(dead_leaves_images(1, 64, seed=6)[0], first[0])
    image = dead_leaves_image(128, torch.Generator().manual_seed(0)).float()
    assert image.shape == (3, 128, 128) and dead_leaves_image(8, torch.Generator()).dtype == torch.uint8
    step = (image[:, :, 1:] - image[:, :, :-1]).abs().amax(0)
    assert (step <= 4).float().mean() > 0.6  # mostly smooth: disc interiors
    assert (step > 40).float().mean() > 0.002  # and sharp disc edges
    assert image.std() > 20  # colours vary


def test_distilled_profile_has_the_narrow_network_and_copies_of_the_stages() -> None:
    teacher = _teacher()
    fast = distill_profile(teacher, dead_leaves_images(4, 64), width=8, recipe=TINY, seed=0)
    assert fast.network is not None and fast.network.width == 8
    assert fast.name == "teacher-fast" and "distilled to width 8" in fast.description
    assert [type(e) for e in fast.effects] == [Blur, Tone]
    for mine, theirs in zip(fast.effects, teacher.effects):
        assert mine is not theirs
        assert all(torch.equal(a, b) for a, b in zip(mine.state_dict().values(), theirs.state_dict().values()))
    assert fast.fitted["distilled_from"] == "teacher" and fast.fitted["teacher_width"] == 64
    assert fast.fitted["images"] == "the given images" and fast.fitted["recipe"]["width"] == 8
    assert "student_vs_teacher_psnr_db" in fast.quality


def test_the_student_learns_the_teacher_and_repeats_from_its_seed() -> None:
    teacher, images = _teacher(), dead_leaves_images(6, 64, seed=1)
    short = distill_profile(teacher, images, width=8, recipe=FitConfig(**{**TINY.as_dict(), "epochs": 1}))
    longer = distill_profile(teacher, images, width=8, recipe=FitConfig(**{**TINY.as_dict(), "epochs": 8}))
    again = distill_profile(teacher, images, width=8, recipe=FitConfig(**{**TINY.as_dict(), "epochs": 8}))
    assert longer.quality["student_vs_teacher_psnr_db"] > short.quality["student_vs_teacher_psnr_db"] + 1.0
    assert all(torch.equal(a, b) for a, b in zip(longer.state_dict().values(), again.state_dict().values()))


def test_distilling_on_a_folder_skips_unreadable_files_and_refuses_too_few_images(tmp_path) -> None:
    folder = tmp_path / "images"
    for index, image in enumerate(dead_leaves_images(3, 48)):
        write_image(image, folder / f"{index}.png")
    (folder / "broken.png").write_bytes(b"not a png")
    write_image(torch.zeros(3, 16, 16, dtype=torch.uint8), folder / "tiny.png")
    lines: list[str] = []
    fast = distill_profile(_teacher(), folder, width=4, recipe=TINY, log=lines.append)
    assert fast.fitted["train_images"] + fast.fitted["validation_images"] == 3
    assert any("broken.png" in line for line in lines) and any("smaller than the 32-pixel" in line for line in lines)
    try:
        distill_profile(_teacher(), [torch.zeros(3, 40, 40)], width=4, recipe=TINY)
    except ValueError as error:
        assert "at least 2 images of at least 32² pixels" in str(error)
    else:
        raise AssertionError("one image was accepted")


def test_a_recipe_object_keeps_its_width_and_seed_unless_told() -> None:
    recipe = FitConfig(**{**TINY.as_dict(), "epochs": 1, "width": 4, "seed": 3})
    fast = distill_profile(_teacher(), dead_leaves_images(3, 48), recipe=recipe)
    assert fast.network.width == 4 and fast.fitted["recipe"]["seed"] == 3
    assert distill_profile(_teacher(), dead_leaves_images(3, 48), recipe=recipe, width=8).network.width == 8


def test_a_profile_without_network_cannot_be_distilled() -> None:
    try:
        distill_profile(CameraProfile(None, [Tone(gamma=1.2)], name="effects-only"), dead_leaves_images(2, 40))
    except ValueError as error:
        assert "has no network to distil" in str(error)
    else:
        raise AssertionError("accepted")


@pytest.mark.slow
def test_cli_distills_on_generated_images_and_never_writes_over_the_teacher(tmp_path, capsys) -> None:
    teacher = _teacher().save(tmp_path / "teacher.safetensors")
    assert main(["distill", str(teacher), "-o", str(teacher), "--epochs", "1", "--quiet"]) == 1
    assert "is the input file itself" in capsys.readouterr().err
    output = tmp_path / "fast.safetensors"
    assert main(["distill", str(teacher), "-o", str(output), "--epochs", "1", "--width", "8", "--quiet"]) == 0
    fast = load_profile(output)
    assert fast.network is not None and fast.network.width == 8 and fast.effect_names == ["blur", "tone"]
    assert fast.fitted["images"] == "generated dead leaves"
    image = torch.rand(1, 3, 40, 40)
    assert F.mse_loss(fast(image), _teacher()(image)) < 0.05  # one epoch already lands near the teacher
