from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from camdegrade.errors import PairsError
from camdegrade.pairs.discovery import (
    AMBIGUOUS,
    NO_CAPTURED,
    NO_CLEAN,
    NO_SUFFIX,
    SIZE_MISMATCH,
    discover_pairs,
    filter_pairs,
)
from camdegrade.pairs.manifest import BAD_ROW, DUPLICATE
from camdegrade.pairs.pair import MISSING, TOO_SMALL, UNREADABLE, Pair
from camdegrade.pairs.pairset import load_pair, split_by_scene


def save(path: Path, size: tuple[int, int] = (32, 24), mode: str = "RGB", seed: int = 0, **options) -> Path:
    """Write a random image of ``size`` = (width, height) in PIL ``mode``."""
    rng = np.random.default_rng(seed)
    width, height = size
    path.parent.mkdir(parents=True, exist_ok=True)
    if mode == "I;16":
        image = Image.fromarray(rng.integers(0, 65536, (height, width), dtype=np.uint16))
    else:
        pixels = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
        image = Image.fromarray(pixels).convert(mode)
    image.save(path, **options)
    return path


def reasons(report) -> dict[str, str]:
    """Map skipped file name (or row label) -> reason category."""
    return {Path(str(path)).name: reason.partition(": ")[0] for path, reason in report.skipped}


# --- clean/ + captured/ folders -------------------------------------------------------------------------------


def test_folder_layout_matches_nested_stems_with_any_extension_case(tmp_path: Path) -> None:
    save(tmp_path / "clean" / "a.png")
    save(tmp_path / "captured" / "a.JPG")
    save(tmp_path / "clean" / "sub" / "deeper" / "b.PNG")
    save(tmp_path / "captured" / "sub" / "deeper" / "b.jpeg")
    (tmp_path / "clean" / "notes.txt").write_text("not an image extension: ignored")

    report = discover_pairs(tmp_path)

    assert [pair.name for pair in report.pairs] == ["a", "sub/deeper/b"]
    assert report.pairs[1].clean == tmp_path / "clean" / "sub" / "deeper" / "b.PNG"
    assert report.pairs[1].captured == tmp_path / "captured" / "sub" / "deeper" / "b.jpeg"
    assert report.pairs[1].scene == "b"
    assert report.skipped == []


def test_folder_layout_reports_unmatched_files_on_both_sides(tmp_path: Path) -> None:
    save(tmp_path / "clean" / "a.png")
    save(tmp_path / "captured" / "a.png")
    save(tmp_path / "clean" / "lonely_clean.png")
    save(tmp_path / "captured" / "sub" / "lonely_capture.jpg")
    save(tmp_path / "captured" / "A.png")  # stems are case-sensitive

    report = discover_pairs(tmp_path)

    assert [pair.name for pair in report.pairs] == ["a"]
    assert reasons(report) == {"lonely_clean.png": NO_CAPTURED, "lonely_capture.jpg": NO_CLEAN, "A.png": NO_CLEAN}
    summary = report.summary()
    assert "1 pair found" in summary and "3 skipped" in summary
    assert f"{NO_CLEAN} (2):" in summary and "captured/sub/lonely_capture.jpg" in summary


def test_folder_layout_reports_ambiguous_stems(tmp_path: Path) -> None:
    save(tmp_path / "clean" / "x.png")
    save(tmp_path / "clean" / "x.jpg")
    save(tmp_path / "captured" / "x.png")
    save(tmp_path / "clean" / "y.png")
    save(tmp_path / "captured" / "y.png")

    report = discover_pairs(tmp_path)

    assert [pair.name for pair in report.pairs] == ["y"]
    categories = [reason.partition(": ")[0] for _, reason in report.skipped]
    assert categories.count(AMBIGUOUS) == 2 and NO_CLEAN in categories


# --- suffix rules ----------------------------------------------------------------------------------------------


def test_suffix_rules_pair_files_recursively_in_one_folder(tmp_path: Path) -> None:
    save(tmp_path / "Canon_chair_11_mean.JPG")
    save(tmp_path / "Canon_chair_11_real.JPG")
    save(tmp_path / "nested" / "plant__4_mean.png")  # double underscore must survive
    save(tmp_path / "nested" / "plant__4_real.PNG")
    save(tmp_path / "nested" / "other.png")  # neither suffix
    save(tmp_path / "orphan_mean.jpg")

    report = discover_pairs(tmp_path, clean_suffix="_mean", captured_suffix="_real")

    assert [(pair.name, pair.scene) for pair in report.pairs] == [
        ("Canon_chair_11", "Canon_chair_11"),
        ("nested/plant__4", "plant__4"),
    ]
    assert reasons(report) == {"other.png": NO_SUFFIX, "orphan_mean.jpg": NO_CAPTURED}


def test_empty_clean_suffix_pairs_name_with_name_copy(tmp_path: Path) -> None:
    save(tmp_path / "cat.jpg")
    save(tmp_path / "cat_copy.jpg")
    save(tmp_path / "dog.jpg")
    save(tmp_path / "bird_copy.JPG")

    report = discover_pairs(tmp_path, clean_suffix="", captured_suffix="_copy")
    # a missing clean suffix means the empty suffix
    same = discover_pairs(tmp_path, captured_suffix="_copy")

    assert [(pair.name, pair.scene) for pair in report.pairs] == [("cat", "cat")]
    assert report.pairs[0].captured.name == "cat_copy.jpg"
    assert same.pairs == report.pairs
    assert reasons(report) == {"dog.jpg": NO_CAPTURED, "bird_copy.JPG": NO_CLEAN}


def test_city100_style_suffixes_give_the_scene_number(tmp_path: Path) -> None:
    save(tmp_path / "001H.PNG")
    save(tmp_path / "001L.PNG")

    report = discover_pairs(tmp_path, clean_suffix="H", captured_suffix="L")

    assert report.pairs[0].scene == "001"


@pytest.mark.parametrize(
    ("clean_suffix", "captured_suffix", "message"),
    [("_a", "_a", "must differ"), ("", "", "must differ"), ("_mean", "_real.JPG", "without the extension")],
)
def test_bad_suffix_rules_are_refused(tmp_path: Path, clean_suffix: str, captured_suffix: str, message: str) -> None:
    save(tmp_path / "x_a.png")
    with pytest.raises(PairsError, match=message):
        discover_pairs(tmp_path, clean_suffix=clean_suffix, captured_suffix=captured_suffix)


# --- CSV manifest ----------------------------------------------------------------------------------------------


def write_csv(path: Path, rows: list[list[str]], encoding: str = "utf-8") -> Path:
    with path.open("w", newline="", encoding=encoding) as handle:
        csv.writer(handle).writerows(rows)
    return path


def test_manifest_resolves_relative_paths_and_keeps_extra_columns(tmp_path: Path) -> None:
    save(tmp_path / "data" / "s1" / "001H.PNG")
    save(tmp_path / "data" / "s1" / "001L.PNG")
    save(tmp_path / "data" / "gt" / "GT_0.png")
    save(tmp_path / "data" / "noisy" / "NOISY_0.png")
    manifest = write_csv(
        tmp_path / "data" / "pairs.csv",
        [
            ["subset", "clean", "captured", "scene"],
            ["city", "s1/001H.PNG", "s1/001L.PNG", ""],
            ["sidd", "gt/GT_0.png", "noisy/NOISY_0.png", "room"],
        ],
    )

    report = discover_pairs(manifest)

    sidd, city = report.pairs  # sorted by name
    assert city.clean == tmp_path / "data" / "s1" / "001H.PNG"
    assert (city.name, city.scene, city.meta["subset"]) == ("s1/001H", "001", "city")
    assert (sidd.name, sidd.scene, sidd.meta) == ("gt/GT_0", "room", {"subset": "sidd", "scene": "room"})


def test_manifest_reports_missing_files_empty_cells_and_duplicates(tmp_path: Path) -> None:
    save(tmp_path / "a.png")
    save(tmp_path / "a_cap.png")
    manifest = write_csv(
        tmp_path / "pairs.csv",
        [
            ["Clean", "Captured"],  # header case and a BOM (below) are tolerated
            ["a.png", "a_cap.png"],
            ["a.png", "a_cap.png"],
            ["gone.png", "a_cap.png"],
            ["a.png", ""],
        ],
        encoding="utf-8-sig",
    )

    report = discover_pairs(manifest)

    assert [pair.name for pair in report.pairs] == ["a"]
    assert reasons(report) == {
        "pairs.csv line 3": DUPLICATE,
        "gone.png": MISSING,
        "pairs.csv line 5": BAD_ROW,
    }


def test_manifest_disambiguates_one_clean_image_captured_twice(tmp_path: Path) -> None:
    save(tmp_path / "a.png")
    save(tmp_path / "shot1.png")
    save(tmp_path / "shot2.png")
    manifest = write_csv(tmp_path / "m.csv", [["clean", "captured"], ["a.png", "shot1.png"], ["a.png", "shot2.png"]])

    names = [pair.name for pair in discover_pairs(manifest).pairs]

    assert len(set(names)) == 2 and "a" in names


def test_manifest_without_required_columns_is_refused(tmp_path: Path) -> None:
    manifest = write_csv(tmp_path / "m.csv", [["input", "target"], ["a.png", "b.png"]])
    with pytest.raises(PairsError, match=r"columns 'clean' and 'captured'.*\['input', 'target'\]"):
        discover_pairs(manifest)


def test_suffix_rules_with_a_manifest_are_refused(tmp_path: Path) -> None:
    manifest = write_csv(tmp_path / "m.csv", [["clean", "captured"]])
    with pytest.raises(PairsError, match="not to a CSV"):
        discover_pairs(manifest, clean_suffix="_mean")


# --- image checks ----------------------------------------------------------------------------------------------


def make_problem_folder(root: Path) -> None:
    save(root / "clean" / "good.png")
    save(root / "captured" / "good.png")
    save(root / "clean" / "corrupt.png")
    (root / "captured" / "corrupt.png").write_bytes(np.random.default_rng(1).bytes(300))
    save(root / "clean" / "tiny.png", size=(8, 8))
    save(root / "captured" / "tiny.png", size=(8, 8))
    save(root / "clean" / "mismatch.png", size=(40, 30))
    save(root / "captured" / "mismatch.png", size=(36, 30))
    save(root / "clean" / "unmatched.png")


def test_unreadable_tiny_and_mismatched_images_are_reported(tmp_path: Path) -> None:
    make_problem_folder(tmp_path)

    report = discover_pairs(tmp_path)

    assert [pair.name for pair in report.pairs] == ["good"]
    categories = sorted(reason.partition(": ")[0] for _, reason in report.skipped)
    assert categories == sorted([UNREADABLE, TOO_SMALL, TOO_SMALL, SIZE_MISMATCH, NO_CAPTURED])
    summary = report.summary()
    assert "captured/corrupt.png" in summary
    assert "clean 40x30 px, captured 36x30 px" in summary
    assert "8x8 px (min_size=16)" in summary


def test_strict_mode_raises_listing_every_problem_at_once(tmp_path: Path) -> None:
    make_problem_folder(tmp_path)

    with pytest.raises(PairsError) as caught:
        discover_pairs(tmp_path, strict=True)

    message = str(caught.value)
    for expected in ("corrupt.png", "tiny.png", "mismatch.png", "unmatched.png", "strict"):
        assert expected in message


def test_size_mismatch_crop_keeps_the_pair_and_loads_centre_crops(tmp_path: Path) -> None:
    save(tmp_path / "clean" / "m.png", size=(40, 30))
    save(tmp_path / "captured" / "m.png", size=(36, 34))

    report = discover_pairs(tmp_path, size_mismatch="crop")
    clean, captured = load_pair(report.pairs[0])

    assert report.pairs[0].crop_to == (30, 36)
    assert clean.shape == captured.shape == (3, 30, 36)
    full_clean = torch.from_numpy(np.array(Image.open(tmp_path / "clean" / "m.png"))).permute(2, 0, 1)
    assert torch.equal(clean, full_clean[:, :, 2:38])
    assert "centre-cropped" in report.summary()


def test_check_images_false_defers_problems_to_load_pair(tmp_path: Path) -> None:
    save(tmp_path / "clean" / "m.png", size=(40, 30))
    save(tmp_path / "captured" / "m.png", size=(36, 30))
    save(tmp_path / "clean" / "corrupt.png")
    (tmp_path / "captured" / "corrupt.png").write_bytes(b"not an image at all")

    report = discover_pairs(tmp_path, check_images=False)

    assert [pair.name for pair in report.pairs] == ["corrupt", "m"]
    with pytest.raises(OSError, match=r"corrupt\.png"):
        load_pair(report.pairs[0])
    with pytest.raises(PairsError, match=r"40x30 px but captured image is 36x30 px"):
        load_pair(report.pairs[1])


def test_exif_orientation_is_honoured_in_discovery_and_loading(tmp_path: Path) -> None:
    exif = Image.Exif()
    exif[0x0112] = 6  # rotate 90° clockwise on display: a 40x24 file shows as 24x40
    save(tmp_path / "clean" / "r.jpg", size=(40, 24), exif=exif.tobytes())
    save(tmp_path / "captured" / "r.png", size=(24, 40))

    report = discover_pairs(tmp_path)
    clean, captured = load_pair(report.pairs[0])

    assert report.skipped == []
    assert clean.shape == captured.shape == (3, 40, 24)


@pytest.mark.parametrize("mode", ["I;16", "P", "RGBA", "L", "LA"])
def test_unusual_modes_are_discovered_and_load_as_rgb_uint8(tmp_path: Path, mode: str) -> None:
    save(tmp_path / "clean" / "x.png", size=(20, 18), mode=mode)
    save(tmp_path / "captured" / "x.png", size=(20, 18))

    clean, captured = load_pair(discover_pairs(tmp_path).pairs[0])

    assert clean.dtype == torch.uint8 and clean.shape == captured.shape == (3, 18, 20)


def test_sixteen_bit_images_are_scaled_to_eight_bits(tmp_path: Path) -> None:
    (tmp_path / "clean").mkdir()
    Image.fromarray(np.full((18, 20), 65535, dtype=np.uint16)).save(tmp_path / "clean" / "w.png")
    save(tmp_path / "captured" / "w.png", size=(20, 18))

    clean, _ = load_pair(discover_pairs(tmp_path).pairs[0])

    assert int(clean.min()) == 255


# --- sources that give nothing ---------------------------------------------------------------------------------


def test_folder_without_layout_says_what_was_tried_and_found(tmp_path: Path) -> None:
    save(tmp_path / "photos" / "x_mean.png")
    with pytest.raises(PairsError, match=r"clean/ and captured/.*suffix.*csv.*found 1 image files.*photos/"):
        discover_pairs(tmp_path)


def test_empty_clean_and_captured_folders_raise(tmp_path: Path) -> None:
    (tmp_path / "clean").mkdir()
    (tmp_path / "captured").mkdir()
    with pytest.raises(PairsError, match=r"no usable .* looked for clean/ and captured/ folders"):
        discover_pairs(tmp_path)


def test_all_files_skipped_raises_with_the_report(tmp_path: Path) -> None:
    save(tmp_path / "clean" / "a.png")
    save(tmp_path / "captured" / "b.png")
    with pytest.raises(PairsError, match=rf"(?s)0 pairs found.*{NO_CAPTURED}.*a\.png"):
        discover_pairs(tmp_path)


def test_missing_source_and_non_csv_file_raise(tmp_path: Path) -> None:
    with pytest.raises(PairsError, match="does not exist"):
        discover_pairs(tmp_path / "nowhere")
    with pytest.raises(PairsError, match=r"not a \.csv"):
        discover_pairs(save(tmp_path / "x.png"))


@pytest.mark.parametrize(("option", "value"), [("size_mismatch", "pad"), ("min_size", 0)])
def test_bad_options_are_refused(tmp_path: Path, option: str, value: object) -> None:
    with pytest.raises(PairsError, match=option):
        discover_pairs(tmp_path, **{option: value})


# --- selection and splits --------------------------------------------------------------------------------------


def make_pairs(scenes: list[str]) -> list[Pair]:
    return [
        Pair(Path(f"{i}c.png"), Path(f"{i}d.png"), f"p{i}", scene, {"subset": "even" if i % 2 == 0 else "odd"})
        for i, scene in enumerate(scenes)
    ]


def test_split_by_scene_never_puts_one_scene_on_both_sides() -> None:
    pairs = make_pairs([f"s{i // 3}" for i in range(30)])  # 10 scenes of 3 pairs

    train, held_out = split_by_scene(pairs, 0.2, seed=3)

    assert len(held_out) == 6 and len(train) == 24
    assert not {pair.scene for pair in train} & {pair.scene for pair in held_out}
    assert split_by_scene(pairs, 0.2, seed=3) == (train, held_out)
    assert split_by_scene(pairs, 2, seed=3)[1] == held_out


def test_split_by_scene_with_named_scenes() -> None:
    pairs = make_pairs(["001", "002", "002", "003"])

    train, held_out = split_by_scene(pairs, ["002"])

    assert [pair.name for pair in held_out] == ["p1", "p2"]
    assert [pair.name for pair in train] == ["p0", "p3"]
    assert split_by_scene(pairs, "002") == (train, held_out)


@pytest.mark.parametrize(("holdout", "message"), [(["999"], "no pair has"), (1.0, "between 0 and 1"), (3, "leaves no")])
def test_split_by_scene_refuses_impossible_holdouts(holdout: object, message: str) -> None:
    with pytest.raises(PairsError, match=message):
        split_by_scene(make_pairs(["a", "b", "c"]), holdout)  # type: ignore[arg-type]


def test_filter_pairs_by_meta_and_path() -> None:
    pairs = make_pairs(["a", "b", "c", "d"])

    assert [pair.name for pair in filter_pairs(pairs, subset="even")] == ["p0", "p2"]
    assert [pair.name for pair in filter_pairs(pairs, subset="odd", path_contains="3c")] == ["p3"]


def test_pairs_are_hashable_despite_their_meta_dict() -> None:
    assert len(set(make_pairs(["a", "a"]))) == 2


# --- the shared real pairs -------------------------------------------------------------------------------------


@pytest.mark.realdata
def test_real_pairs_manifest(real_pairs_dir: Path) -> None:
    report = discover_pairs(real_pairs_dir / "pairs.csv")

    assert len(report.pairs) == 200 and report.skipped == []
    iphone = filter_pairs(report.pairs, subset="city100_iPhoneX", path_contains="City100_iPhoneX")
    assert len(iphone) == 71
    assert iphone[0].scene == "001"
    train, held_out = split_by_scene(iphone, 0.2, seed=0)
    assert len(train) + len(held_out) == 71 and held_out
