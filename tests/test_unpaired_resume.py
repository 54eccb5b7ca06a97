"""The unpaired fit's checkpoint (:mod:`camdegrade.fitting.unpaired.checkpoint`, issue 43's "resumable"): a fit
interrupted in a step (Ctrl-C: a ``KeyboardInterrupt`` raised from the step) and resumed from its checkpoint gives
the profile an uninterrupted fit gives, byte for byte (``fit_minutes``, wall time, set equal); a checkpoint written
for other images or options, a damaged one and a file that is no such checkpoint are refused by a typed error that
names the file and what differs; the CLI writes one, says to resume on Ctrl-C, resumes, and removes it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from bad_inputs import one_line_error, run_cli
from camdegrade import CameraProfile
from camdegrade._support.pixels import unit_to_bytes
from camdegrade._support.seeds import derived_generator
from camdegrade.effects import Blur, Noise, Tone, Vignetting
from camdegrade.errors import CheckpointError, FitInterrupted
from camdegrade.fitting.unpaired import fit_unpaired
from camdegrade.fitting.unpaired.checkpoint import CHECKPOINT_KEY
from camdegrade.fitting.unpaired.steps.noise import NoiseMatch
from camdegrade.fitting.unpaired.steps.spectrum import TransferMatch
from camdegrade.fitting.unpaired.steps.vignetting import VignettingMatch
from camdegrade.io import write_image
from camdegrade.profile import load_profile
from camdegrade.synthetic import dead_leaves_images

torch.set_num_threads(1)
COUNT, SIZE = 8, 128
#: A small camera whose fit keeps stages before the interrupted step and after it.
CAMERA = (Blur(1.5), Vignetting(-0.4), Noise(levels=torch.full((3, 4), 4.0 / 255), linear=False), Tone(gamma=1.3))
#: The fast tests' stages: two that are kept, each fitted more than once, the noise through the vignetting.
FEW = ("vignetting", "noise")


def _scenes(seed: int) -> list[torch.Tensor]:
    """Dead-leaves scenes with a flat grey patch each (flat pixels for the noise), 8-bit."""
    scenes = []
    for index, image in enumerate(dead_leaves_images(COUNT, SIZE, seed=seed)):
        generator = derived_generator(seed, "flat-patch", index)
        image, side = image.clone(), SIZE * 3 // 8
        top, left = (int(v) for v in torch.randint(0, SIZE - side, (2,), generator=generator))
        image[:, top : top + side, left : left + side] = int(torch.randint(40, 220, (1,), generator=generator))
        scenes.append(image)
    return scenes


@pytest.fixture(scope="module")
def sides() -> tuple[list[torch.Tensor], list[torch.Tensor]]:
    """(captures of scenes of seed 2 by :data:`CAMERA`, clean scenes of seed 1), 8-bit."""
    captures = CameraProfile(None, list(CAMERA)).simulate(_scenes(2), seed=7)
    return [unit_to_bytes(image) for image in captures], _scenes(1)


def _bytes(profile: CameraProfile, path: Path) -> bytes:
    profile.fitted["fit_minutes"] = 0.0  # wall time: the one entry that differs between two runs
    profile.save(path)
    return path.read_bytes()


@pytest.fixture(scope="module")
def whole(sides, tmp_path_factory: pytest.TempPathFactory) -> tuple[bytes, Path]:
    """The uninterrupted fast fit (named "cam", as the CLI names it) as saved bytes, and its finished checkpoint."""
    folder = tmp_path_factory.mktemp("whole")
    profile = fit_unpaired(*sides, effects=FEW, name="cam", checkpoint=folder / "fit.ckpt.safetensors")
    return _bytes(profile, folder / "cam.safetensors"), folder / "fit.ckpt.safetensors"


def _interrupt(patch: pytest.MonkeyPatch, step: type, error: type[BaseException] = KeyboardInterrupt, call=1) -> None:
    """``step``'s ``call``-th proposal (counted from now) raises ``error``; the others run."""
    original, calls = step.propose, []

    def stop(self, fit):
        calls.append(self)
        if len(calls) == call:
            raise error()
        return original(self, fit)

    patch.setattr(step, "propose", stop)


@pytest.fixture(scope="module")
def interrupted_once(sides, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """The checkpoint of the fast fit (seed 0) interrupted in its second noise step ("noise again", step 12 of 18:
    vignetting and noise kept, the noise to be fitted again through the vignetting), and the interruption's text."""
    checkpoint = tmp_path_factory.mktemp("interrupted") / "fit.ckpt.safetensors"
    with pytest.MonkeyPatch.context() as patch:
        _interrupt(patch, NoiseMatch, call=2)
        with pytest.raises(FitInterrupted) as raised:
            fit_unpaired(*sides, effects=FEW, checkpoint=checkpoint)
    return checkpoint, str(raised.value)


@pytest.fixture
def written(interrupted_once: tuple[Path, str], tmp_path: Path) -> Path:
    """A copy of that checkpoint, the test's own."""
    copy = tmp_path / "fit.ckpt.safetensors"
    copy.write_bytes(interrupted_once[0].read_bytes())
    return copy


def test_an_interrupted_fit_resumed_gives_the_bytes_of_an_uninterrupted_one(
    sides, whole: tuple[bytes, Path], interrupted_once: tuple[Path, str], written: Path, tmp_path: Path
) -> None:
    assert interrupted_once[1].endswith(
        f"during step 12 of 18 (noise again); checkpoint {str(interrupted_once[0])!r} holds the 11 steps before it"
    )
    saved = load_profile(written)
    assert saved.effect_names == ["vignetting", "noise"] and saved.fitted[CHECKPOINT_KEY]["steps_done"] == 11
    resumed = fit_unpaired(*sides, effects=FEW, name="cam", checkpoint=written, resume=True)
    assert _bytes(resumed, tmp_path / "resumed.safetensors") == whole[0]


def test_a_resumed_fit_runs_only_the_steps_after_the_checkpoint(
    sides, written: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Steps 1 to 10 are not run again: a vignetting step that ran would fail; the noise steps after it run."""
    _interrupt(monkeypatch, VignettingMatch, RuntimeError)
    resumed = fit_unpaired(*sides, effects=FEW, checkpoint=written, resume=True)
    assert resumed.effect_names == ["vignetting", "noise"]


@pytest.mark.slow
def test_the_default_stages_resumed_after_the_blur_give_the_same_bytes(sides, tmp_path: Path) -> None:
    """Every default stage; interrupted in "blur and sharpening" (step 7), resumed, against a fit never
    interrupted."""
    uninterrupted = fit_unpaired(*sides)
    checkpoint = tmp_path / "fit.ckpt.safetensors"
    with pytest.MonkeyPatch.context() as patch:
        _interrupt(patch, TransferMatch)
        with pytest.raises(FitInterrupted, match=r"during step 7 of 18 \(blur and sharpening\)"):
            fit_unpaired(*sides, checkpoint=checkpoint)
    resumed = fit_unpaired(*sides, checkpoint=checkpoint, resume=True)
    assert "blur" in uninterrupted.effect_names and len(uninterrupted.effect_names) >= 4, uninterrupted.fitted["kept"]
    assert _bytes(resumed, tmp_path / "resumed.safetensors") == _bytes(uninterrupted, tmp_path / "u.safetensors")


def test_a_finished_checkpoint_resumes_to_the_same_profile_without_running_a_step(
    sides, whole: tuple[bytes, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The library leaves the checkpoint after the fit (the caller removes it once the profile is saved)."""
    finished = whole[1]
    assert load_profile(finished).fitted[CHECKPOINT_KEY]["steps_done"] == 18
    _interrupt(monkeypatch, NoiseMatch, RuntimeError)  # a step that ran would fail
    resumed = fit_unpaired(*sides, effects=FEW, name="cam", checkpoint=finished, resume=True)
    assert _bytes(resumed, tmp_path / "resumed.safetensors") == whole[0]


@pytest.mark.parametrize(
    ("change", "named"),
    [
        ("one capture", "other captured (CAPTURED) images"),
        ("clean images", "other clean (--clean) images"),
        ("seed", "seed=0, this fit has seed=1"),
        ("effects", "effects=['vignetting', 'noise'], this fit has effects=['noise']"),
        ("sensor_scale", "sensor_scale='auto', this fit has sensor_scale=0.5"),
        ("max_images", "max_images=None, this fit has max_images=20"),
    ],
)
def test_a_checkpoint_of_other_images_or_options_is_refused_by_name(
    change: str, named: str, sides, written: Path
) -> None:
    captures, clean = list(sides[0]), list(sides[1])
    options: dict = {"effects": FEW}
    if change == "one capture":
        captures[3] = captures[3].clone()
        captures[3][0, 0, 0] ^= 1  # one level of one pixel
    elif change == "clean images":
        clean = clean[::-1]
    else:
        options[change] = {"seed": 1, "effects": ("noise",), "sensor_scale": 0.5, "max_images": 20}[change]
    before = written.read_bytes()
    with pytest.raises(CheckpointError, match=r"^resume: checkpoint .*fit\.ckpt\.safetensors") as raised:
        fit_unpaired(captures, clean, checkpoint=written, resume=True, **options)
    assert named in str(raised.value) and "start a new fit without resume" in str(raised.value), raised.value
    assert written.read_bytes() == before  # a refusal leaves the checkpoint as it was


def _rewritten_state(path: Path, **changes) -> None:
    profile = load_profile(path)
    profile.fitted = {CHECKPOINT_KEY: {**profile.fitted[CHECKPOINT_KEY], **changes}}
    profile.save(path)


@pytest.mark.parametrize(
    ("damage", "named"),
    [
        ("truncated", "is not a camdegrade unpaired fit's checkpoint (profile "),
        ("a profile", "(a profile without 'unpaired_checkpoint' in 'fitted')"),
        ("not safetensors", "is not a camdegrade unpaired fit's checkpoint (profile "),
        ("records", "(damaged: 'records' is [1, 2])"),
        ("steps_done", "counts 19 of 18 steps done"),
        ("version", "of layout version 1 (found 2"),
    ],
)
def test_a_damaged_or_foreign_checkpoint_is_refused_naming_the_file(
    damage: str, named: str, sides, written: Path
) -> None:
    if damage == "truncated":
        written.write_bytes(written.read_bytes()[:-40])
    elif damage == "a profile":
        CameraProfile(None, [Tone(gamma=1.2)], name="a camera").save(written)
    elif damage == "not safetensors":
        written.write_text(json.dumps({"camdegrade_checkpoint": 1}))
    else:
        _rewritten_state(written, **{damage: {"records": [1, 2], "steps_done": 19, "version": 2}[damage]})
    with pytest.raises(CheckpointError) as raised:
        fit_unpaired(*sides, effects=FEW, checkpoint=written, resume=True)
    assert str(written) in str(raised.value) and named in str(raised.value), raised.value


def test_resume_without_a_checkpoint_file_is_refused_before_any_image_is_read(tmp_path: Path) -> None:
    missing = tmp_path / "none.ckpt.safetensors"
    with pytest.raises(FileNotFoundError, match=r"resume: checkpoint .*none\.ckpt\.safetensors' does not exist"):
        fit_unpaired(tmp_path / "no folder", checkpoint=missing, resume=True)
    with pytest.raises(ValueError, match=r"resume=True needs checkpoint=PATH"):
        fit_unpaired(tmp_path / "no folder", resume=True)
    with pytest.raises(ValueError, match=r"checkpoint must end in '\.safetensors', got checkpoint="):
        fit_unpaired(tmp_path / "no folder", checkpoint=tmp_path / "fit.ckpt")


def test_an_interrupted_write_leaves_the_last_whole_checkpoint(
    sides, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ctrl-C while the checkpoint of step 6 is written: the file still holds the 5 steps before, whole, and no
    temporary file is left beside it."""
    checkpoint = tmp_path / "fit.ckpt.safetensors"
    original, writes = CameraProfile.save, []

    def interrupted_sixth(self, path):
        writes.append(path)
        if len(writes) == 6:
            raise KeyboardInterrupt
        return original(self, path)

    monkeypatch.setattr(CameraProfile, "save", interrupted_sixth)
    with pytest.raises(FitInterrupted, match=r"during step 6 of 18 .* holds the 5 steps before it"):
        fit_unpaired(*sides, effects=FEW, checkpoint=checkpoint)
    monkeypatch.setattr(CameraProfile, "save", original)
    assert load_profile(checkpoint).fitted[CHECKPOINT_KEY]["steps_done"] == 5
    assert sorted(path.name for path in tmp_path.iterdir()) == ["fit.ckpt.safetensors"]


def _folders(tmp_path: Path, sides) -> tuple[Path, Path]:
    folders = tmp_path / "captured", tmp_path / "clean"
    for folder, images in zip(folders, sides, strict=True):
        for index, image in enumerate(images):
            write_image(image, folder / f"{index:02d}.png")
    return folders


def test_the_cli_says_to_resume_on_ctrl_c_resumes_and_removes_the_checkpoint(
    sides, whole: tuple[bytes, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """The default checkpoint beside the output; the resumed profile is the library's uninterrupted one."""
    captured, clean = _folders(tmp_path, sides)
    output, checkpoint = tmp_path / "out" / "cam.safetensors", tmp_path / "out" / "cam.ckpt.safetensors"
    command = ["fit", "--unpaired", captured, "--clean", clean, "-o", output, "--effects", *FEW, "--quiet"]
    with monkeypatch.context() as patch:
        _interrupt(patch, NoiseMatch)
        code, _, err = run_cli(command, capsys)
    line = one_line_error(err)
    assert code == 130 and "during step 6 of 18 (noise)" in line and line.endswith("; run again with --resume"), err
    assert checkpoint.is_file() and not output.exists()
    code, out, err = run_cli([*command, "--resume"], capsys)
    assert code == 0, err
    assert "resumed from" in out and "after step 5 of 18 (vignetting again)" in out, out
    assert output.is_file() and not checkpoint.exists()
    assert _bytes(load_profile(output), tmp_path / "cli.safetensors") == whole[0]


def test_the_cli_refuses_a_checkpoint_of_another_fit_in_one_line(
    sides, written: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    captured, clean = _folders(tmp_path, sides)
    output = tmp_path / "cam.safetensors"
    command = ["fit", "--unpaired", captured, "--clean", clean, "-o", output, "--checkpoint", written, "--resume"]
    code, _, err = run_cli([*command, "--effects", *FEW, "--seed", "4", "--quiet"], capsys)
    line = one_line_error(err)
    assert code == 1 and "seed=0, this fit has seed=4" in line and str(written) in line, err
    assert not output.exists() and written.is_file()


def test_the_cli_refuses_a_checkpoint_that_is_not_safetensors_or_is_the_output(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    base = ["fit", "--unpaired", tmp_path, "-o", tmp_path / "cam.safetensors", "--checkpoint"]
    code, _, err = run_cli([*base, tmp_path / "cam.ckpt"], capsys)
    assert code == 1 and "--checkpoint must end in .safetensors" in one_line_error(err)
    code, _, err = run_cli([*base, tmp_path / "cam.safetensors"], capsys)
    assert code == 1 and "--checkpoint must differ from --output" in one_line_error(err)
    assert list(tmp_path.iterdir()) == []


def test_the_same_pixels_in_another_memory_layout_give_the_same_profile(
    sides, whole: tuple[bytes, Path], tmp_path: Path
) -> None:
    """The clean scenes are channels-last tensors; the same pixels laid out contiguously (as files are read) give
    the same bytes: the images are made contiguous when read, so the checkpoint's fingerprint, which hashes the
    pixels and not their layout, matches only fits that give the same profile. Before, the noise stage differed."""
    captures, clean = sides
    assert not clean[0].is_contiguous()
    contiguous = fit_unpaired(captures, [image.contiguous() for image in clean], effects=FEW, name="cam")
    assert _bytes(contiguous, tmp_path / "contiguous.safetensors") == whole[0]
