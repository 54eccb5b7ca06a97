"""AlbumentationsCameraDegrade inside real albumentations pipelines; skipped when albumentations is absent.

tests/conftest.py sets NO_ALBUMENTATIONS_UPDATE=1, so importing albumentations asks no server for a newer version.
"""

from __future__ import annotations

import json
import pickle
import random

import numpy as np
import pytest
import torch

A = pytest.importorskip("albumentations")
ToTensorV2 = pytest.importorskip("albumentations.pytorch").ToTensorV2

from camdegrade import CameraDegrade  # noqa: E402
from camdegrade.data import DegradedDataset, Union  # noqa: E402
from camdegrade.integrations.albumentations import AlbumentationsCameraDegrade  # noqa: E402
from profiles_for_tests import stochastic_profile  # noqa: E402


@pytest.fixture(scope="module")
def profile_path(tmp_path_factory):
    """A stochastic profile on disk: serialisable by name/path, and its noise makes every call different."""
    return str(stochastic_profile().save(tmp_path_factory.mktemp("profiles") / "noisy.safetensors"))


def hwc_image(index: int = 0, height: int = 12, width: int = 16) -> np.ndarray:
    return np.random.default_rng(100 + index).integers(0, 256, (height, width, 3), dtype=np.uint8)


def run(pipeline, images) -> list[np.ndarray]:
    return [pipeline(image=image)["image"] for image in images]


def test_uint8_and_float_hwc_keep_shape_dtype_and_input(profile_path):
    degrade = AlbumentationsCameraDegrade(profile_path)
    degrade.set_random_seed(0)
    image = hwc_image()
    before = image.copy()
    out = degrade(image=image)["image"]
    assert out.shape == image.shape and out.dtype == np.uint8 and out.flags.c_contiguous
    assert not np.array_equal(out, image)
    assert np.array_equal(image, before)  # not modified in place

    unit = image.astype(np.float32) / 255
    out_float = degrade(image=unit)["image"]
    assert out_float.shape == unit.shape and out_float.dtype == np.float32
    assert out_float.min() >= 0.0 and out_float.max() <= 1.0

    read_only = image.copy()
    read_only.flags.writeable = False  # what np.asarray(PIL image) gives; torch would warn on sharing it
    assert degrade(image=read_only)["image"].shape == image.shape


def test_same_compose_seed_same_bytes(profile_path):
    images = [hwc_image(i) for i in range(8)]

    def pipeline(seed):
        return A.Compose([A.HorizontalFlip(p=0.5), AlbumentationsCameraDegrade(profile_path, p=0.5)], seed=seed)

    first, again, other = run(pipeline(7), images), run(pipeline(7), images), run(pipeline(8), images)
    assert all(np.array_equal(a, b) for a, b in zip(first, again))
    assert not all(np.array_equal(a, b) for a, b in zip(first, other))
    camera_skipped = [
        np.array_equal(out, image) or np.array_equal(out, image[:, ::-1]) for out, image in zip(first, images)
    ]
    assert 0 < camera_skipped.count(False) < len(images)  # p=0.5 decides per call, from the Compose's random state


def test_reuses_camera_degrade_with_a_generator_from_the_drawn_seed(profile_path):
    pipeline = A.Compose([AlbumentationsCameraDegrade(profile_path)], seed=3, save_applied_params=True)
    image = hwc_image()
    result = pipeline(image=image)
    [(name, params)] = result["applied_transforms"]
    assert name == "AlbumentationsCameraDegrade"
    generator = torch.Generator().manual_seed(params["seed"])
    expected = CameraDegrade(profile_path).degrade_with(torch.from_numpy(image).permute(2, 0, 1), generator=generator)
    assert np.array_equal(result["image"], expected.permute(1, 2, 0).numpy())


def test_replay_compose_replays_exactly(profile_path):
    pipeline = A.ReplayCompose([AlbumentationsCameraDegrade(profile_path)])
    image = hwc_image()
    first = pipeline(image=image)
    assert np.array_equal(A.ReplayCompose.replay(first["replay"], image=image)["image"], first["image"])
    assert not np.array_equal(pipeline(image=image)["image"], first["image"])  # a new call draws anew


def test_images_target_gives_each_image_its_own_noise(profile_path):
    degrade = AlbumentationsCameraDegrade(profile_path)
    degrade.set_random_seed(0)
    stack = np.stack([hwc_image()] * 3)
    out = degrade(images=stack)["images"]
    assert out.shape == stack.shape and out.dtype == np.uint8
    assert not np.array_equal(out[0], out[1]) and not np.array_equal(out[1], out[2])


def test_pickled_copy_continues_the_same_random_sequence(profile_path):
    pipeline = A.Compose([AlbumentationsCameraDegrade(profile_path, p=0.5)], seed=11)
    run(pipeline, [hwc_image()])  # advance the state before copying, as a DataLoader would after a few items
    copy = pickle.loads(pickle.dumps(pipeline))
    images = [hwc_image(i) for i in range(4)]
    assert all(np.array_equal(a, b) for a, b in zip(run(pipeline, images), run(copy, images)))


def test_to_dict_from_dict_round_trip(profile_path):
    pipeline = A.Compose(
        [A.HorizontalFlip(p=0.5), AlbumentationsCameraDegrade(profile_path, precision="float32", p=0.5)]
    )
    serialised = A.to_dict(pipeline)
    saved = serialised["transform"]["transforms"][1]
    assert saved == {
        "__class_fullname__": "camdegrade.integrations.albumentations.AlbumentationsCameraDegrade",
        "p": 0.5,
        "profile": profile_path,
        "precision": "float32",
    }
    rebuilt = A.from_dict(json.loads(json.dumps(serialised)))
    assert isinstance(rebuilt.transforms[1], AlbumentationsCameraDegrade)
    pipeline.set_random_seed(5)
    rebuilt.set_random_seed(5)
    images = [hwc_image(i) for i in range(4)]
    assert all(np.array_equal(a, b) for a, b in zip(run(pipeline, images), run(rebuilt, images)))


def test_profile_objects_work_but_do_not_serialise():
    degrade = AlbumentationsCameraDegrade(stochastic_profile())
    degrade.set_random_seed(0)
    assert degrade(image=hwc_image())["image"].shape == hwc_image().shape
    assert "test-stochastic" in repr(degrade)
    with pytest.raises(NotImplementedError, match=r"profile\.save"):
        A.to_dict(A.Compose([degrade]))


def test_bad_input_names_the_rule(profile_path):
    degrade = AlbumentationsCameraDegrade(profile_path)
    with pytest.raises(ValueError, match=r"\(H, W, 3\).*shape \(12, 16\)"):
        degrade(image=hwc_image()[..., 0])
    with pytest.raises(ValueError, match=r"shape \(12, 16, 4\)"):
        degrade(image=np.zeros((12, 16, 4), dtype=np.uint8))
    with pytest.raises(TypeError, match="dtype=int16"):
        degrade(image=np.zeros((12, 16, 3), dtype=np.int16))
    with pytest.raises(ValueError, match="p must be a probability"):
        AlbumentationsCameraDegrade(profile_path, p=1.5)
    with pytest.raises(ValueError, match="precision"):
        AlbumentationsCameraDegrade(profile_path, precision="float16")


class AlbumentationsImages(torch.utils.data.Dataset):
    """A dataset whose own pipeline is albumentations, ending in ToTensorV2 (uint8 CHW), as DegradedDataset needs."""

    def __init__(self, length: int) -> None:
        self.images = [hwc_image(i) for i in range(length)]
        self.pipeline = A.Compose([A.HorizontalFlip(p=1.0), ToTensorV2()])  # deterministic: clean views comparable

    def __len__(self) -> int:
        return len(self.images)

    def __getitem__(self, index: int):
        return self.pipeline(image=self.images[index])["image"], index


def test_union_around_an_albumentations_dataset_counts_and_bytes(profile_path):
    """The paper's exact union: albumentations inside the dataset, DegradedDataset around it."""
    first, again = ([*DegradedDataset(AlbumentationsImages(6), profile_path, policy=Union(), seed=4)] for _ in range(2))
    assert len(first) == 12
    assert all(torch.equal(a[0], b[0]) and a[1] == b[1] for a, b in zip(first, again))  # same seed, same bytes
    for source in range(6):
        views = [image for image, index in first if index == source]
        clean = torch.from_numpy(np.ascontiguousarray(hwc_image(source)[:, ::-1])).permute(2, 0, 1)
        assert [torch.equal(image, clean) for image in views] == [True, False]  # once clean, once degraded


class SameImage(torch.utils.data.Dataset):
    """Four copies of one image through ``pipeline``: workers that repeat each other's randomness repeat outputs."""

    def __init__(self, pipeline) -> None:
        self.pipeline = pipeline

    def __len__(self) -> int:
        return 4

    def __getitem__(self, index: int) -> np.ndarray:
        return self.pipeline(image=hwc_image())["image"]


def seed_worker(worker_id: int) -> None:
    """The worker_init_fn of docs/integrations.md: torch seeds each worker differently, every epoch."""
    torch.utils.data.get_worker_info().dataset.pipeline.set_random_seed(torch.initial_seed())


def test_reseeding_each_worker_as_documented(profile_path):
    def load(worker_init_fn):
        dataset = SameImage(A.Compose([AlbumentationsCameraDegrade(profile_path)], seed=1))
        generator = torch.Generator().manual_seed(0)  # the workers' base seed
        loader = torch.utils.data.DataLoader(
            dataset, batch_size=1, num_workers=2, worker_init_fn=worker_init_fn, generator=generator
        )
        return [batch[0] for batch in loader]  # items 0, 2 from worker 0; 1, 3 from worker 1

    repeated = load(None)
    assert torch.equal(repeated[0], repeated[1])  # each worker holds a copy of the same random state
    reseeded = load(seed_worker)
    assert not torch.equal(reseeded[0], reseeded[1])
    assert all(torch.equal(a, b) for a, b in zip(reseeded, load(seed_worker)))  # and reproducible


def test_one_shared_generator_decorrelates_decisions_reproducibly(profile_path):
    """docs/integrations.md: a seeded Compose gives each transform its own generators seeded alike, so equal-p
    transforms decide together; set_random_state shares one pair of generators instead."""
    image = hwc_image()

    def decisions(share: bool) -> list[tuple[str, ...]]:
        transforms = [A.HorizontalFlip(p=0.5), AlbumentationsCameraDegrade(profile_path, p=0.5)]
        pipeline = A.Compose(transforms, seed=None if share else 2, save_applied_params=True)
        if share:
            pipeline.set_random_state(np.random.default_rng(2), random.Random(2))
        return [tuple(name for name, _ in pipeline(image=image)["applied_transforms"]) for _ in range(16)]

    assert {len(applied) for applied in decisions(share=False)} <= {0, 2}  # always both or neither
    shared = decisions(share=True)
    assert any(len(applied) == 1 for applied in shared)
    assert shared == decisions(share=True)


# --- targets move with the image -----------------------------------------------------------------------------------


def _warp_profile():
    from camdegrade import CameraProfile, load_profile
    from camdegrade.effects import Misalignment

    return CameraProfile(None, [*load_profile("lowcost-robot-sim").effects, Misalignment(5.0, 3.0, 2.0)], name="warp")


def _square(x0: int, y0: int, side: int = 20, height: int = 96, width: int = 128):
    image = np.full((height, width, 3), 40, dtype=np.uint8)
    image[y0 : y0 + side, x0 : x0 + side] = 220
    mask = np.zeros((height, width), dtype=np.uint8)
    mask[y0 : y0 + side, x0 : x0 + side] = 1
    return image, mask


def _object(image: np.ndarray) -> np.ndarray:
    return image.mean(-1) > 130


def test_mask_bboxes_and_keypoints_follow_the_warp():
    """Before, masks, boxes and keypoints passed through while the image moved by several pixels."""
    image, mask = _square(12, 10)
    pipeline = A.Compose(
        [AlbumentationsCameraDegrade(_warp_profile())],
        bbox_params=A.BboxParams(format="pascal_voc", label_fields=[]),
        keypoint_params=A.KeypointParams(format="xy", remove_invisible=False),
        seed=0,
    )
    out = pipeline(image=image, mask=mask, bboxes=[[12, 10, 32, 30]], keypoints=[[21.5, 19.5]])
    found = _object(out["image"])
    moved = out["mask"].astype(bool)
    assert (moved & found).sum() / (moved | found).sum() >= 0.95
    ys, xs = found.nonzero()
    assert np.abs(np.asarray(out["bboxes"][0]) - [xs.min(), ys.min(), xs.max() + 1, ys.max() + 1]).max() <= 1.0
    x, y = out["keypoints"][0]
    assert abs(x - (found * np.arange(128)[None]).sum() / found.sum()) <= 0.5  # the square's centre
    assert abs(y - (found * np.arange(96)[:, None]).sum() / found.sum()) <= 0.5


def test_keypoint_angles_and_scales_turn_with_the_warp():
    from camdegrade import CameraProfile
    from camdegrade.effects import Misalignment

    degrade = AlbumentationsCameraDegrade(CameraProfile(None, [Misalignment(5.0, 3.0, 2.0)], name="turn"))
    pipeline = A.Compose([degrade], keypoint_params=A.KeypointParams(format="xyas", angle_in_degrees=True), seed=0)
    out = pipeline(image=_square(12, 10)[0], keypoints=[[60.0, 40.0, 30.0, 2.0]])
    angle, scale = out["keypoints"][0][2:]
    assert abs(angle - 28.0) <= 0.01 and abs(scale - 2.0) <= 1e-4  # turned by the 2° counter-clockwise rotation


def test_targets_replay_with_the_image(tmp_path):
    from camdegrade import CameraProfile
    from camdegrade.effects import Misalignment

    jittered = CameraProfile(None, [Misalignment(shift_std=3.0, angle_std=2.0)], name="jitter")
    pipeline = A.ReplayCompose([AlbumentationsCameraDegrade(str(jittered.save(tmp_path / "jitter.safetensors")))])
    pipeline.set_random_seed(0)  # unseeded, a draw of under half a pixel and a few hundredths of a degree moves nothing
    image, mask = _square(50, 40)
    first = pipeline(image=image, mask=mask, masks=np.stack([mask, 1 - mask]))
    replayed = A.ReplayCompose.replay(first["replay"], image=image, mask=mask, masks=np.stack([mask, 1 - mask]))
    assert all(np.array_equal(first[key], replayed[key]) for key in ("image", "mask", "masks"))
    found = _object(first["image"])
    moved = first["mask"].astype(bool)
    assert (moved & found).sum() / (moved | found).sum() >= 0.95 and not np.array_equal(first["mask"], mask)
    assert np.array_equal(first["masks"][0], first["mask"])
    inside = (slice(10, -10), slice(10, -10))  # outside the frame's content, every moved mask holds 0
    assert np.array_equal(first["masks"][1][inside], 1 - first["mask"][inside])


def test_targets_beside_images_that_move_differently_are_refused():
    from camdegrade import CameraProfile
    from camdegrade.effects import Misalignment

    jittered = CameraProfile(None, [Misalignment(shift_std=3.0)], name="jitter")
    image, mask = _square(50, 40)
    with pytest.raises(ValueError, match="cannot move targets"):
        AlbumentationsCameraDegrade(jittered)(images=np.stack([image, image]), masks=np.stack([mask, mask]))


def test_targets_stay_when_the_profile_moves_no_pixels(profile_path):
    image, mask = _square(12, 10)
    out = AlbumentationsCameraDegrade(profile_path)(image=image, mask=mask)
    assert out["mask"] is mask
