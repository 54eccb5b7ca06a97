"""More bad inputs beyond issue 17's list, found by red-teaming camdegrade's file handling, profile metadata and
epochs. Each test failed before its fix: a silent wrong result (an image written from NaN or 0..255 floats, a
profile name ``None`` read back as ``'None'``, a truncated profile shown by ``info``), an untyped or misleading error
(an ``AttributeError``, a message naming a temporary file, an ``OverflowError``), or a batch that stopped or left
files out without saying so."""

from __future__ import annotations

import os
import struct
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from bad_inputs import good_image, one_line_error, profile_file, run_cli
from camdegrade import CameraProfile, DegradedDataset, load_profile
from camdegrade._profile_format.header import read_header
from camdegrade.data import BatchDegrade
from camdegrade.effects import Vignetting
from camdegrade.errors import ImageError, ProfileError
from camdegrade.io import iter_images, read_image, read_image_size, write_image
from profiles_for_tests import deterministic_profile, stochastic_profile


def _names(folder: Path) -> list[str]:
    return sorted(os.listdir(folder))


# --- writing images ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "image, error, message",
    [
        (torch.full((3, 4, 4), 200.0), ValueError, r"written from \[0, 1\], got values in \[200, 200\].*1/255"),
        (torch.full((3, 4, 4), float("nan")), ValueError, r"contains NaN or infinite values"),
        (torch.full((3, 4, 4), 5, dtype=torch.int16), TypeError, r"uint8 or floating point.*dtype=torch\.int16"),
        (np.zeros((3, 4, 4), dtype=np.uint8), TypeError, r"must be a torch\.Tensor.*got ndarray"),
    ],
)
def test_write_image_refuses_what_it_cannot_write_faithfully(tmp_path: Path, image, error, message: str) -> None:
    """These were written silently (NaN as black, 0..255 floats and int16 as white) or failed with AttributeError."""
    with pytest.raises(error, match=message) as info:
        write_image(image, tmp_path / "out.png")
    assert "out.png" in str(info.value)
    assert _names(tmp_path) == []


@pytest.mark.parametrize("suffix", [".gif", ".pdf"])
def test_write_image_writes_only_formats_camdegrade_reads_back(tmp_path: Path, suffix: str) -> None:
    """GIF re-quantised the degraded image to 256 colours and PDF wrapped it in a document, silently."""
    with pytest.raises(ValueError, match=rf"an image extension camdegrade reads \(.*\.png.*\), got '.*out\{suffix}'"):
        write_image(torch.zeros(3, 4, 4, dtype=torch.uint8), tmp_path / f"out{suffix}")
    assert _names(tmp_path) == []


@pytest.mark.parametrize("suffix, limit", [(".jpg", 65_500), (".webp", 16_383)])
def test_an_image_larger_than_its_format_stores_names_the_file(tmp_path: Path, suffix: str, limit: int) -> None:
    """It failed inside the encoder: a bare 'broken data stream' (and libjpeg's own line on stderr) or a
    ValueError, neither naming the file. An ImageError (an OSError) lets a batch list it and go on."""
    target = tmp_path / f"wide{suffix}"
    with pytest.raises(ImageError, match=rf"'.*wide\{suffix}'.* at most {limit} px a side, got height 1 and width"):
        write_image(torch.zeros(3, 1, limit + 1, dtype=torch.uint8), target)
    assert _names(tmp_path) == []


def test_apply_to_a_jpeg_too_wide_is_one_line(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    source = tmp_path / "wide.png"
    Image.fromarray(np.zeros((1, 65_600, 3), dtype=np.uint8)).save(source)
    profile = CameraProfile(None, []).save(tmp_path / "p.safetensors")
    code, _, err = run_cli(["apply", profile, source, tmp_path / "wide.jpg"], capfd)
    assert code == 1 and "at most 65500 px a side" in one_line_error(err)  # libjpeg printed a line of its own


def test_writing_over_a_folder_names_the_target_not_a_temporary(tmp_path: Path) -> None:
    """The whole file was written to a temporary, then os.replace failed naming '.out.png.<hex>.tmp'."""
    (tmp_path / "out.png").mkdir()
    (tmp_path / "p.safetensors").mkdir()
    with pytest.raises(IsADirectoryError, match=r"^cannot write '.*out\.png': it is a folder$"):
        write_image(torch.zeros(3, 4, 4, dtype=torch.uint8), tmp_path / "out.png")
    with pytest.raises(IsADirectoryError, match=r"^cannot write '.*p\.safetensors': it is a folder$"):
        stochastic_profile().save(tmp_path / "p.safetensors")
    assert _names(tmp_path) == ["out.png", "p.safetensors"]


def test_a_failure_to_create_the_temporary_names_the_target() -> None:
    """Files cannot be created in /proc: the error named the temporary ('/proc/.x.png.<hex>.tmp')."""
    if not Path("/proc/self").is_dir():
        pytest.skip("no /proc here")
    with pytest.raises(OSError, match=r"^cannot write '/proc/x\.png': ") as info:
        write_image(torch.zeros(3, 4, 4, dtype=torch.uint8), "/proc/x.png")
    assert ".tmp" not in str(info.value)


def test_saving_a_profile_where_nothing_can_be_written_is_an_oserror() -> None:
    """safetensors raised its own SafetensorError (not an OSError), naming a temporary of its own."""
    if not Path("/proc/self").is_dir():
        pytest.skip("no /proc here")
    with pytest.raises(OSError, match=r"^cannot write '/proc/x\.safetensors'"):
        stochastic_profile().save("/proc/x.safetensors")


@pytest.mark.skipif(sys.platform != "linux", reason="needs a file system that takes any bytes as a name")
def test_a_file_name_that_is_not_utf8_is_written(tmp_path: Path) -> None:
    """Such a name (it arrives with surrogate escapes) made the temporary's name fail to encode: a
    UnicodeEncodeError, a ValueError, which stopped a whole ``apply`` batch at that file."""
    target = Path(os.fsdecode(os.fsencode(tmp_path) + b"/caf\xe9.png"))
    write_image(torch.full((3, 4, 4), 9, dtype=torch.uint8), target)
    assert read_image(target).unique().tolist() == [9]
    assert os.listdir(os.fsencode(tmp_path)) == [b"caf\xe9.png"]


# --- finding and reading images ---------------------------------------------------------------------------------


def test_entries_that_cannot_be_read_are_reported_not_left_out(tmp_path: Path, capsys) -> None:
    """A dangling link, a link loop and a FIFO named like images were left out of a batch silently (status 0)."""
    folder = tmp_path / "in"
    good_image(folder / "good.png")
    (folder / "dangling.png").symlink_to(tmp_path / "gone.png")
    (folder / "loop1.png").symlink_to(folder / "loop2.png")
    (folder / "loop2.png").symlink_to(folder / "loop1.png")
    os.mkfifo(folder / "pipe.png")
    assert [path.name for path in iter_images(folder)] == [
        "dangling.png",
        "good.png",
        "loop1.png",
        "loop2.png",
        "pipe.png",
    ]
    with pytest.raises(ImageError, match=r"dangling\.png': it is a symbolic link that leads to no file"):
        read_image(folder / "dangling.png")  # was: "no such file", for a name the folder listing shows
    profile = CameraProfile(None, []).save(tmp_path / "p.safetensors")
    code, out, err = run_cli(["apply", profile, folder, tmp_path / "out"], capsys)
    assert code == 1 and "4 of 5 image(s) could not be degraded" in one_line_error(err)
    assert _names(tmp_path / "out") == ["good.png"]
    assert "pipe.png: cannot read image" in out and "not a regular file" in out


def test_a_folder_that_cannot_be_listed_is_reported(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Path.rglob skips folders it may not list, so their images vanished from a batch without a word. (Simulated:
    the tests may run as root, who may list anything.)"""
    folder = tmp_path / "in"
    good_image(folder / "a.png")
    good_image(folder / "locked" / "b.png")
    real_scandir = os.scandir

    def scandir(path=None):
        if Path(os.fsdecode(path)).name == "locked":
            raise PermissionError(13, "Permission denied", os.fsdecode(path))
        return real_scandir(path)

    monkeypatch.setattr(os, "scandir", scandir)
    assert list(iter_images(folder)) == [folder / "a.png", folder / "locked"]
    with pytest.raises(ImageError, match=r"locked': it is a folder"):
        read_image(folder / "locked")


def _png_with_exif_after_pixels(path: Path, height: int, width: int, orientation: int) -> Path:
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    exif = Image.Exif()
    exif[0x0112] = orientation
    rows = b"".join(b"\x00" + bytes(range(3 * width)) for _ in range(height))
    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    data = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(rows))
    path.write_bytes(data + chunk(b"eXIf", exif.tobytes()[6:]) + chunk(b"IEND", b""))
    return path


def test_read_image_size_sees_exif_after_a_pngs_pixels(tmp_path: Path) -> None:
    """read_image applies it (Pillow finds it when decoding); read_image_size ignored it, so pair discovery took a
    rotated image's size for the unrotated one."""
    path = _png_with_exif_after_pixels(tmp_path / "late.png", 5, 12, orientation=6)
    assert tuple(read_image(path).shape[1:]) == (12, 5)
    assert read_image_size(path) == (12, 5)


def test_read_image_size_of_a_rotated_tiff_matches_read_image(tmp_path: Path) -> None:
    """Recent Pillow releases report a TIFF's size with its orientation applied already; read_image_size turned it a
    second time."""
    exif = Image.Exif()
    exif[0x0112] = 6
    path = tmp_path / "rotated.tif"
    Image.fromarray(np.zeros((5, 12, 3), dtype=np.uint8)).save(path, exif=exif.tobytes())
    assert read_image_size(path) == tuple(read_image(path).shape[1:]) == (12, 5)


# --- profiles -----------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("cut", ["short", "long"])
def test_info_refuses_a_profile_whose_data_does_not_fill_the_file(tmp_path: Path, cut: str) -> None:
    """load_profile refused these, but read_header (``camdegrade info``) read the header and said all was well."""
    path = stochastic_profile().save(tmp_path / "p.safetensors")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2] if cut == "short" else data + b"junk")
    expected = "is cut short" if cut == "short" else "has bytes after its data"
    with pytest.raises(ProfileError, match=rf"corrupt or truncated \(.*the file {expected}"):
        read_header(path)
    with pytest.raises(ProfileError, match="corrupt or truncated"):
        load_profile(path)


@pytest.mark.parametrize(
    "metadata, message",
    [
        ({"effects": {"name": "noise"}}, r"'effects' must be a list of \{'name', 'config'\} entries, got an object"),
        ({"effects": None}, r"'effects' must be a list of .* entries, got null$"),
        ({"name": ["a", "b"]}, r"'name' must be a string, got a list \['a', 'b'\]"),
        ({"description": {"x": 1}}, r"'description' must be a string, got an object"),
        ({"fitted": [1, 2]}, r"'fitted' must be an object, got a list \[1, 2\]"),
        ({"package_version": 3}, r"'package_version' must be a string, got a number 3"),
    ],
)
def test_metadata_entries_of_the_wrong_type_are_named(tmp_path: Path, metadata: dict, message: str) -> None:
    """A dict of effects was read key by key ("effect entry ... 'name'"), null as "'NoneType' object is not
    iterable", a list name became the text "['a', 'b']", a list 'fitted' failed with a dict() message."""
    path = profile_file(tmp_path / "m.safetensors", stochastic_profile(), metadata)
    for read in (load_profile, read_header):
        with pytest.raises(ProfileError, match=message) as info:
            read(path)
        assert str(info.value).startswith(f"profile {str(path)!r} has invalid metadata: ")


def test_a_profile_file_that_cannot_be_opened_is_a_profile_error(tmp_path: Path, monkeypatch) -> None:
    """A PermissionError escaped as such. (Simulated: the tests may run as root.)"""
    path = stochastic_profile().save(tmp_path / "p.safetensors")
    real_open = Path.open

    def no_permission(self: Path, *args, **kwargs):
        if self == path:
            raise PermissionError(13, "Permission denied", str(self))
        return real_open(self, *args, **kwargs)

    monkeypatch.setattr(Path, "open", no_permission)
    for read in (load_profile, read_header):
        with pytest.raises(ProfileError, match=r"^cannot read profile '.*p\.safetensors': Permission denied$"):
            read(path)


@pytest.mark.parametrize(
    "keyword, value, message",
    [
        ("name", None, r"name must be a str, got name=None \(NoneType\)"),
        ("name", 5, r"name must be a str, got name=5 \(int\)"),
        ("description", b"x", r"description must be a str"),
        ("fitted", [1, 2], r"fitted must be a mapping \(JSON object\) or None, got list"),
    ],
)
def test_profile_text_and_records_must_have_their_types(tmp_path: Path, keyword: str, value, message: str) -> None:
    """``name=None`` was saved as null and loaded back as the name 'None'; a list 'fitted' failed in dict()."""
    with pytest.raises(TypeError, match=message):
        CameraProfile(None, [], **{keyword: value})


def test_saving_metadata_that_is_not_json_names_it_and_writes_nothing(tmp_path: Path) -> None:
    profile = CameraProfile(None, [], name="cam", fitted={"pairs": {1, 2}})
    with pytest.raises(TypeError, match=r"cannot save profile 'cam': its metadata \(fitted, quality\) must be JSON"):
        profile.save(tmp_path / "p.safetensors")
    assert _names(tmp_path) == []


def test_saving_a_profile_on_the_meta_device_is_refused(tmp_path: Path) -> None:
    """It failed in an effect's value check with "Tensor.item() cannot be called on meta tensors"."""
    profile = CameraProfile(None, [Vignetting(-0.3)], name="cam").to("meta")
    with pytest.raises(ValueError, match=r"cannot save profile 'cam': tensors on the meta device hold no values"):
        profile.save(tmp_path / "p.safetensors")
    assert _names(tmp_path) == []


# --- epochs -------------------------------------------------------------------------------------------------------


def test_an_epoch_too_large_to_store_is_named() -> None:
    """set_epoch(2**70) raised a bare OverflowError; BatchDegrade(epoch=2**70) was taken silently (folded onto
    another epoch's keys)."""
    dataset = DegradedDataset([torch.zeros(3, 8, 8)], deterministic_profile(), seed=0)
    batch = BatchDegrade(deterministic_profile(), p=1.0, seed=0)
    for call in (
        lambda: dataset.set_epoch(2**70),
        lambda: batch.set_epoch(2**70),
        lambda: batch(torch.zeros(2, 3, 8, 8), epoch=2**70),
    ):
        with pytest.raises(ValueError, match=rf"^epoch must be an integer <= {2**63 - 1}, got epoch={2**70}$"):
            call()


# --- found by the red team in the command line, the engine and fitting (fixed outside its files) ----------------


def _profile(tmp_path: Path) -> Path:
    return stochastic_profile().save(tmp_path / "cam.safetensors")


def _pairs(tmp_path: Path) -> Path:
    from test_fit import make_pairs_folder

    return make_pairs_folder(tmp_path / "pairs", count=4)


def test_a_huge_thread_count_is_an_option_error_not_a_crash(tmp_path: Path, capsys) -> None:
    """--threads 100000 made OpenMP fail to allocate its pool: a MemoryError traceback, then a segfault."""
    image = good_image(tmp_path / "a.png")
    code, _, err = run_cli(["apply", _profile(tmp_path), image, tmp_path / "o.png", "--threads", "100000"], capsys)
    assert code == 2 and "--threads: must be an integer from 1 to" in one_line_error(err)


def test_a_device_whose_backend_is_not_built_in_is_an_option_error(tmp_path: Path, capsys) -> None:
    """--device privateuseone printed a ModuleNotFoundError traceback."""
    image = good_image(tmp_path / "a.png")
    code, _, err = run_cli(
        ["apply", _profile(tmp_path), image, tmp_path / "o.png", "--device", "privateuseone"], capsys
    )
    assert code == 2 and "--device 'privateuseone' cannot be used here" in one_line_error(err)


def test_fit_never_writes_its_checkpoint_or_profile_over_a_pair_image(tmp_path: Path, capsys) -> None:
    """`fit pairs --checkpoint pairs/clean/img0.png` overwrote that image with the checkpoint, then deleted it."""
    from test_fit import QUICK

    pairs = _pairs(tmp_path)
    image = pairs / "clean" / "img0.png"
    before = image.read_bytes()
    code, _, err = run_cli(["fit", pairs, "-o", tmp_path / "p.safetensors", "--checkpoint", image, *QUICK], capsys)
    assert code == 1 and "is the input file itself" in one_line_error(err)
    assert image.read_bytes() == before and not (tmp_path / "p.safetensors").exists()


def test_diagnose_never_writes_its_reports_over_an_input_or_over_each_other(tmp_path: Path, capsys) -> None:
    """--json pairs/m.csv or --html pairs/clean/x.png overwrote the inputs; --json X --html X replaced one report
    with the other."""
    pairs = _pairs(tmp_path)
    manifest = tmp_path / "m.csv"
    manifest.write_text(
        "clean,captured\n" + "".join(f"pairs/clean/img{i}.png,pairs/captured/img{i}.png\n" for i in range(4))
    )
    profile = _profile(tmp_path)
    for argv in (
        ["diagnose", profile, manifest, "--json", manifest],
        ["diagnose", profile, pairs, "--html", pairs / "clean" / "img1.png"],
    ):
        before = Path(argv[-1]).read_bytes()
        code, _, err = run_cli(argv, capsys)
        assert code == 1 and "is the input file itself" in one_line_error(err)
        assert Path(argv[-1]).read_bytes() == before
    code, _, err = run_cli(["diagnose", profile, pairs, "--json", tmp_path / "r", "--html", tmp_path / "r"], capsys)
    assert code == 1 and "--json and --html name the same file" in one_line_error(err)


def test_a_long_pairs_error_is_one_line_on_stderr_with_the_report_on_stdout(tmp_path: Path, capsys) -> None:
    """`fit pairs --clean-suffix _x` printed the whole pair report on stderr."""
    from test_fit import QUICK

    code, out, err = run_cli(
        ["fit", _pairs(tmp_path), "-o", tmp_path / "p.safetensors", "--clean-suffix", "_x", *QUICK], capsys
    )
    assert code == 1 and "no usable (clean, captured) pairs found" in one_line_error(err)
    assert "found in" in out  # the report's first line


def test_unpaired_diagnosis_skips_a_truncated_image_and_reports_it(tmp_path: Path, capsys) -> None:
    """`diagnose --real` stopped the whole run at one truncated capture."""
    from bad_inputs import cut_image

    clean, real = tmp_path / "clean", tmp_path / "real"
    for index in range(4):
        good_image(clean / f"{index}.png", (48, 48), seed=index)
        good_image(real / f"{index}.png", (48, 48), seed=10 + index)
    cut_image(real / "broken.png", size=(48, 48))
    code, out, err = run_cli(
        ["diagnose", _profile(tmp_path), clean, "--real", real, "--json", tmp_path / "r.json"], capsys
    )
    assert code == 1 and "broken.png" in out and "could not be read" in one_line_error(err)
    assert (tmp_path / "r.json").exists()


@pytest.mark.slow
def test_file_names_that_are_not_utf8_are_printed_escaped(tmp_path: Path) -> None:
    """Under PYTHONIOENCODING=utf-8 the progress line of such a name raised UnicodeEncodeError and stopped apply."""
    import subprocess

    folder = tmp_path / "in"
    good_image(folder / "a.png")
    name = os.fsdecode(b"caf\xe9.png")
    good_image(folder / name)
    env = {**os.environ, "PYTHONIOENCODING": "utf-8"}
    command = [
        sys.executable,
        "-m",
        "camdegrade",
        "apply",
        "lowcost-robot-sim",
        str(folder),
        str(tmp_path / "o"),
    ]
    result = subprocess.run(command, capture_output=True, env=env, check=False)
    assert result.returncode == 0, result.stderr
    assert len(list((tmp_path / "o").iterdir())) == 2


def test_a_nested_tensor_is_refused_with_a_type_error() -> None:
    """A nested tensor gave `RuntimeError: Internal error`."""
    import warnings

    from camdegrade import CameraDegrade

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # torch's "prototype stage" notice for strided nested tensors
        nested = torch.nested.nested_tensor([torch.rand(3, 4, 4), torch.rand(3, 5, 5)])
    with pytest.raises(TypeError, match="got a nested tensor"):
        CameraDegrade(deterministic_profile())(nested)


@pytest.mark.parametrize(
    "options, error, message",
    [
        ({"device": "bogus"}, ValueError, r"device must be a torch device usable here, got device='bogus'"),
        ({"device": "meta"}, ValueError, r"device 'meta' holds no data"),
        ({"name": 5}, TypeError, r"name must be a str, got name=5"),
    ],
)
def test_fit_profile_refuses_bad_arguments_before_training(tmp_path: Path, options: dict, error, message: str) -> None:
    """Raw torch errors, a failure only after training (name=5), and 'tone' split into letters."""
    from camdegrade import fit_profile

    with pytest.raises(error, match=message):
        fit_profile(tmp_path / "never-read", **options)
    with pytest.raises(TypeError, match="pairs must be a folder"):
        fit_profile(None)  # type: ignore[arg-type]


def test_a_recipe_takes_one_effect_name_as_a_name_not_its_letters() -> None:
    from camdegrade.fitting import FitConfig

    with pytest.raises(ValueError, match=r"effects must be effect names .* got unknown \['tonne'\]"):
        FitConfig.recipe("fast").replace(effects="tonne")
    assert FitConfig.recipe("fast").replace(effects="tone").option("effects") == ("tone",)


def test_fit_lists_manifest_rows_naming_missing_files_and_exits_1(tmp_path: Path, capsys) -> None:
    """The profile was fitted on the other rows and fit exited 0, the missing files said only in the report."""
    from test_fit import QUICK

    pairs = _pairs(tmp_path)
    manifest = pairs / "m.csv"
    rows = "".join(f"clean/img{i}.png,captured/img{i}.png\n" for i in range(4))
    manifest.write_text("clean,captured\n" + rows + "clean/gone.png,captured/gone.png\n")
    code, _, err = run_cli(["fit", manifest, "-o", tmp_path / "p.safetensors", *QUICK], capsys)
    assert code == 1 and "could not be read" in one_line_error(err)
    assert (tmp_path / "p.safetensors").exists()


def test_manifest_rows_naming_one_file_twice_or_a_folder_are_reported(tmp_path: Path) -> None:
    from camdegrade.pairs.discovery import discover_pairs

    pairs = _pairs(tmp_path)
    manifest = pairs / "m.csv"
    manifest.write_text(
        "clean,captured\nclean/img0.png,captured/img0.png\nclean/img1.png,clean/img1.png\nclean,captured/img2.png\n"
    )
    report = discover_pairs(manifest)
    reasons = [reason for _, reason in report.skipped]
    assert len(report.pairs) == 1
    assert any("clean and captured are the same file" in reason for reason in reasons)
    assert any("not a regular file" in reason for reason in reasons)


def test_info_piped_into_a_reader_that_stops_early_is_quiet(tmp_path: Path) -> None:
    """`camdegrade info ... | head -1` printed a BrokenPipeError."""
    import subprocess

    command = f"{sys.executable} -m camdegrade info city100-iphonex | head -1"
    result = subprocess.run(command, shell=True, capture_output=True, text=True, check=False)
    assert result.stdout.count("\n") == 1 and "Error" not in result.stderr and "Traceback" not in result.stderr


def test_a_seed_of_thousands_of_digits_is_named_as_out_of_range(tmp_path: Path, capsys) -> None:
    """Python refuses to parse integers of more than 4,300 digits: the seed was reported as 'must be an integer'."""
    image = good_image(tmp_path / "a.png")
    seed = "9" * 5000
    code, _, err = run_cli(["apply", _profile(tmp_path), image, tmp_path / "o.png", "--seed", seed], capsys)
    line = one_line_error(err)
    assert code == 2 and "must be an integer from -2**63 to 2**64 - 1" in line and "(5000 digits)" in line
