"""CameraDegrade compatibility battery, modelled on torchvision's check_transform / check_kernel."""

from __future__ import annotations

import pickle
import threading
from pathlib import Path

import PIL.Image
import pytest
import torch
from torch.utils.data import DataLoader, Dataset
from torchvision import tv_tensors
from torchvision.transforms import v2
from torchvision.transforms.v2 import functional as TF

import camdegrade.engine as engine_module
from camdegrade import CameraDegrade
from profiles_for_tests import deterministic_profile, stochastic_profile


@pytest.fixture(scope="module")
def still() -> CameraDegrade:
    return CameraDegrade(deterministic_profile())


def uint8_images(*shape: int, seed: int = 0) -> torch.Tensor:
    return torch.randint(0, 256, shape, dtype=torch.uint8, generator=torch.Generator().manual_seed(seed))


def float_images(*shape: int, seed: int = 0) -> torch.Tensor:
    return torch.rand(shape, generator=torch.Generator().manual_seed(seed))


@pytest.mark.parametrize("make", [uint8_images, float_images])
def test_input_is_not_modified_in_place(make):
    image = make(2, 3, 12, 10)
    before, version = image.clone(), image._version
    CameraDegrade(stochastic_profile(), seed=0)(image)
    assert image._version == version
    assert torch.equal(image, before)


@pytest.mark.parametrize("dtype", [torch.uint8, torch.float32, torch.float64, torch.float16, torch.bfloat16])
def test_dtype_shape_and_range_preserved(still, dtype):
    image = uint8_images(2, 3, 9, 14) if dtype == torch.uint8 else float_images(2, 3, 9, 14).to(dtype)
    out = still(image)
    assert out.dtype == dtype and out.shape == image.shape and out.device == image.device
    if dtype.is_floating_point:
        assert float(out.min()) >= 0.0 and float(out.max()) <= 1.0


def test_output_differs_from_input(still):
    image = uint8_images(1, 3, 32, 32)
    assert not torch.equal(still(image), image)


@pytest.mark.parametrize(
    "wrap",
    [tv_tensors.Image, lambda t: tv_tensors.Video(t[None]), lambda t: t],
    ids=["Image", "Video", "tensor"],
)
def test_output_type_equals_input_type(still, wrap):
    image = wrap(uint8_images(3, 16, 16))
    out = still(image)
    assert type(out) is type(image)
    assert out.shape == image.shape


def test_pil_rgb_in_pil_out(still):
    image = TF.to_pil_image(uint8_images(3, 20, 24))
    out = still(image)
    assert isinstance(out, PIL.Image.Image) and out.mode == "RGB" and out.size == image.size
    assert torch.equal(TF.pil_to_tensor(out), still(TF.pil_to_tensor(image)))


def test_batched_equals_unbatched(still):
    batch = uint8_images(4, 3, 15, 21)
    one_by_one = torch.stack([still(image) for image in batch])
    assert torch.equal(still(batch), one_by_one)
    nested = batch.reshape(2, 2, 3, 15, 21)
    assert torch.equal(still(nested).reshape(4, 3, 15, 21), one_by_one)


@pytest.mark.parametrize("dtype", [torch.uint8, torch.float32])
def test_cpu_chunks_give_the_same_bytes_as_one_pass(monkeypatch, dtype):
    """Batches are degraded in cache-sized chunks on the CPU; params are sliced per chunk, so the bytes match."""
    batch = uint8_images(5, 3, 24, 20)
    batch = batch if dtype == torch.uint8 else batch.float() / 255
    degrade = CameraDegrade(stochastic_profile(), seed=3)
    params = degrade.make_params([batch])
    monkeypatch.setattr(engine_module, "CHUNK_PIXELS", 10**9)
    whole = degrade.transform(batch, params)
    monkeypatch.setattr(engine_module, "CHUNK_PIXELS", 2 * 24 * 20)  # chunks of 2, 2 and 1 frames
    assert torch.equal(degrade.transform(batch, params), whole)


def test_empty_batch_keeps_its_shape(still):
    empty = torch.zeros(0, 3, 8, 8, dtype=torch.uint8)
    out = still(empty)
    assert out.shape == (0, 3, 8, 8) and out.dtype == torch.uint8


def test_same_seed_gives_identical_bytes():
    image = uint8_images(3, 3, 20, 20)
    first = CameraDegrade(stochastic_profile(), seed=7)
    second = CameraDegrade(stochastic_profile(), seed=7)
    assert torch.equal(first(image), second(image))
    assert torch.equal(first(image), second(image))  # the sequence continues identically
    assert not torch.equal(
        CameraDegrade(stochastic_profile(), seed=8)(image), CameraDegrade(stochastic_profile(), seed=7)(image)
    )


def test_replay_with_params_is_exact():
    degrade = CameraDegrade(stochastic_profile(), p=0.5, seed=3)
    image = uint8_images(8, 3, 10, 10)
    params = degrade.make_params([image])
    assert torch.equal(degrade.transform(image, params), degrade.transform(image, params))


def test_p_zero_returns_input_unchanged():
    image = uint8_images(5, 3, 11, 11)
    out = CameraDegrade(stochastic_profile(), p=0.0, seed=0)(image)
    assert torch.equal(out, image)


def test_per_sample_probability_degrades_a_subset_exactly_as_p_one():
    image = uint8_images(64, 3, 8, 8)
    half = CameraDegrade(deterministic_profile(), p=0.5, seed=1)
    full = CameraDegrade(deterministic_profile(), p=1.0)
    out, degraded_all = half(image), full(image)
    changed = [not torch.equal(out[i], image[i]) for i in range(64)]
    assert 16 <= sum(changed) <= 48
    for i in range(64):
        assert torch.equal(out[i], degraded_all[i] if changed[i] else image[i])


def test_video_frames_share_one_decision():
    video = tv_tensors.Video(uint8_images(6, 4, 3, 8, 8))  # 6 videos of 4 frames
    out = CameraDegrade(deterministic_profile(), p=0.5, seed=2)(video)
    for clip_in, clip_out in zip(video, out):
        frames_changed = {not torch.equal(a, b) for a, b in zip(clip_in, clip_out)}
        assert len(frames_changed) == 1


def test_pickle_round_trip_continues_the_same_sequence():
    degrade = CameraDegrade(stochastic_profile(), seed=5)
    image = uint8_images(2, 3, 9, 9)
    degrade(image)
    clone = pickle.loads(pickle.dumps(degrade))
    assert torch.equal(clone(image), degrade(image))


def test_sample_structure_and_untouched_items(still):
    image = tv_tensors.Image(uint8_images(3, 16, 16))
    boxes = tv_tensors.BoundingBoxes([[1, 2, 8, 9]], format="XYXY", canvas_size=(16, 16))
    mask = tv_tensors.Mask(torch.zeros(16, 16, dtype=torch.uint8))
    path = Path("a/b.png")
    sample = {
        "image": image,
        "boxes": boxes,
        "mask": mask,
        "label": 3,
        "name": "x",
        "none": None,
        "path": path,
        "extra": [torch.ones(2)],
    }
    out = still(sample)
    assert set(out) == set(sample)
    assert isinstance(out["image"], tv_tensors.Image) and not torch.equal(out["image"], image)
    for key in ("boxes", "mask", "label", "name", "none", "path"):
        assert out[key] is sample[key]
    assert out["extra"][0] is sample["extra"][0]  # plain tensors are not images when an Image is present


def test_tuple_sample_keeps_target(still):
    label = tv_tensors.Mask(torch.ones(8, 8, dtype=torch.uint8))
    image, target = uint8_images(3, 8, 8), {"mask": label}
    out_image, out_target = still((image, target))
    assert out_target == target and out_target["mask"] is label and out_image.shape == image.shape


def test_inside_compose_before_normalize(still):
    pipeline = v2.Compose(
        [v2.ToImage(), still, v2.ToDtype(torch.float32, scale=True), v2.Normalize([0.5] * 3, [0.5] * 3)]
    )
    out = pipeline(PIL.Image.new("RGB", (20, 10), (200, 100, 50)))
    assert out.shape == (3, 10, 20) and out.dtype == torch.float32


class _Images(Dataset):
    def __len__(self) -> int:
        return 6

    def __getitem__(self, index: int):
        return uint8_images(3, 12, 12, seed=index), index


def test_dataloader_with_two_workers(still):
    dataset = _Images()
    loader = DataLoader(dataset, batch_size=3, num_workers=2)
    labels, images = [], []
    for batch, label in loader:
        images.append(still(batch))
        labels.append(label)
    assert torch.cat(labels).tolist() == list(range(6))

    class Degraded(_Images):
        def __getitem__(self, index):
            image, label = super().__getitem__(index)
            return still(image), label

    worker_images = torch.cat([b for b, _ in DataLoader(Degraded(), batch_size=3, num_workers=2)])
    assert torch.equal(worker_images, torch.cat(images))


def test_threads_share_one_transform(still):
    images = [uint8_images(3, 16, 16, seed=i) for i in range(8)]
    expected = [still(image) for image in images]
    results: dict[int, torch.Tensor] = {}

    def work(i: int) -> None:
        results[i] = still(images[i])

    threads = [threading.Thread(target=work, args=(i,)) for i in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert all(torch.equal(results[i], expected[i]) for i in range(8))


def test_no_autograd_graph_is_kept(still):
    image = float_images(1, 3, 8, 8).requires_grad_()
    out = still(image)
    assert not out.requires_grad and out.grad_fn is None


def test_profile_on_its_own_device_is_used_without_a_copy(still):
    assert still.profile_on(torch.device("cpu")) is still.profile


def test_dtype_change_and_weight_reload_are_picked_up():
    degrade = CameraDegrade(deterministic_profile())
    image = uint8_images(1, 3, 12, 12)
    before = degrade(image)
    degrade.double()
    assert torch.equal(degrade(image), before)  # computed on a float32 copy, same result
    with torch.no_grad():
        for tensor in degrade.profile.network.state_dict().values():
            tensor.mul_(0.5)
    assert not torch.equal(degrade(image), before)  # the cached copy was rebuilt from the new weights


def test_seeded_transform_draws_differently_in_each_worker_and_repeats_across_runs():
    degrade = CameraDegrade(stochastic_profile(), seed=0)

    class Same(Dataset):
        def __len__(self) -> int:
            return 4

        def __getitem__(self, index: int):
            return degrade(torch.full((3, 8, 8), 128, dtype=torch.uint8))

    def run():
        return torch.cat(list(DataLoader(Same(), batch_size=1, num_workers=2)))

    first, second = run(), run()
    assert torch.equal(first, second)
    assert not torch.equal(first[0], first[1])  # items 0 and 1 come from different workers


@pytest.mark.parametrize("mode", ["L", "RGBA", "P", "CMYK", "I;16"])
def test_non_rgb_pil_modes_are_refused(still, mode):
    with pytest.raises(ValueError, match=rf"mode '{mode}'.*convert to 'RGB'"):
        still(PIL.Image.new(mode, (8, 8)))


@pytest.mark.parametrize("channels", [1, 2, 4])
def test_wrong_channel_count(still, channels):
    with pytest.raises(ValueError, match=r"\[\.\.\., 3, H, W\].*got shape"):
        still(uint8_images(channels, 8, 8))


@pytest.mark.parametrize("dtype", [torch.int32, torch.int64, torch.bool, torch.uint16])
def test_unsupported_dtype(still, dtype):
    with pytest.raises(TypeError, match=r"uint8 and floating-point.*dtype=torch\."):
        still(torch.zeros(3, 8, 8, dtype=dtype))


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_non_finite_input(still, bad):
    image = float_images(3, 8, 8)
    image[0, 1, 1] = bad
    with pytest.raises(ValueError, match="NaN or infinite"):
        still(image)


@pytest.mark.parametrize("p", [-0.1, 1.5, "0.5", True])
def test_bad_probability(p):
    with pytest.raises(ValueError, match=r"p must be a probability from 0 to 1, got p="):
        CameraDegrade(deterministic_profile(), p=p)


def test_bad_profile_argument():
    with pytest.raises(TypeError, match=r"profile must be a CameraProfile.*got int"):
        CameraDegrade(3)


def test_images_of_different_shapes_in_one_sample_are_refused():
    with pytest.raises(ValueError, match="share a shape"):
        CameraDegrade(stochastic_profile(), seed=0)(
            tv_tensors.Image(uint8_images(3, 8, 8)), tv_tensors.Image(uint8_images(3, 9, 8))
        )


def test_degrade_with_an_explicit_generator_matches_a_seeded_transform():
    image = uint8_images(4, 3, 10, 10)
    seeded = CameraDegrade(stochastic_profile(), p=0.5, seed=11)
    explicit = CameraDegrade(stochastic_profile(), p=0.5)
    assert torch.equal(explicit.degrade_with(image, generator=torch.Generator().manual_seed(11)), seeded(image))
    forced = explicit.degrade_with(image, generator=torch.Generator().manual_seed(11), p=1.0)
    assert all(not torch.equal(forced[i], image[i]) for i in range(4))
    with pytest.raises(ValueError, match="p must be a probability"):
        explicit.degrade_with(image, generator=None, p=2.0)
