"""Hugging Face ``datasets`` under DegradedDataset: the documented recipe, on tiny in-memory datasets (no downloads).

Skipped when ``datasets`` is absent.
"""

from __future__ import annotations

import hashlib
import operator

import numpy as np
import PIL.Image
import pytest
import torch
from torch.utils.data import DataLoader
from torchvision.transforms import v2
from torchvision.transforms.v2 import functional as TF

datasets = pytest.importorskip("datasets")

from camdegrade.data import DegradedDataset, DegradedIterableDataset, Union  # noqa: E402
from profiles_for_tests import stochastic_profile  # noqa: E402

ITEMS = 6
MODES = ("RGB", "L", "RGBA")  # what real image datasets mix; the recipe converts every one to RGB


@pytest.fixture(scope="module")
def noisy():
    return stochastic_profile()


@pytest.fixture(scope="module")
def hf_dataset():
    """``ITEMS`` rows ``{"image": PIL image, "label": int, "index": int}``, built in memory."""
    images = []
    for index in range(ITEMS):
        pixels = np.random.default_rng(index).integers(0, 256, (10, 14, 3), dtype=np.uint8)
        images.append(PIL.Image.fromarray(pixels).convert(MODES[index % len(MODES)]))
    return datasets.Dataset.from_dict({"image": images, "label": [i % 3 for i in range(ITEMS)], "index": range(ITEMS)})


def to_rgb_tensors(batch: dict) -> dict:
    """The recipe's ``with_transform`` function: a batch of rows in, the same columns out, images as RGB uint8."""
    batch["image"] = [TF.pil_to_tensor(image.convert("RGB")) for image in batch["image"]]
    return batch


def to_rgb_pil(batch: dict) -> dict:
    batch["image"] = [image.convert("RGB") for image in batch["image"]]
    return batch


def digest(image: torch.Tensor) -> str:
    return hashlib.sha256(image.contiguous().numpy().tobytes()).hexdigest()[:16]


def test_union_of_a_with_transform_dataset_counts_and_bytes(hf_dataset, noisy):
    source = hf_dataset.with_transform(to_rgb_tensors)
    union = DegradedDataset(source, noisy, policy=Union(), seed=0)
    assert len(union) == 2 * ITEMS
    assert union.column_names == ["image", "label", "index"]  # unknown attributes reach the datasets.Dataset
    items = [union[j] for j in range(len(union))]
    for source_index in range(ITEMS):
        clean_sample = source[source_index]
        clean, degraded = items[2 * source_index], items[2 * source_index + 1]
        for view in (clean, degraded):
            assert set(view) == {"image", "label", "index"} and view["index"] == source_index
            assert view["label"] == clean_sample["label"] and view["image"].dtype == torch.uint8
        assert torch.equal(clean["image"], clean_sample["image"])  # once clean ...
        assert not torch.equal(degraded["image"], clean_sample["image"])  # ... once degraded
        assert torch.equal(degraded["image"], union.degrade_sample(clean_sample, source_index)["image"])

    again = DegradedDataset(source, noisy, policy=Union(), seed=0)
    assert all(torch.equal(a["image"], b["image"]) for a, b in zip(items, again))  # same seed, same bytes
    again.set_epoch(1)
    next_epoch = [again[j]["image"] for j in range(len(again))]
    assert all(torch.equal(a["image"], b) for a, b in zip(items[::2], next_epoch[::2]))  # clean views unchanged
    assert not any(torch.equal(a["image"], b) for a, b in zip(items[1::2], next_epoch[1::2]))  # fresh noise


def test_set_transform_gives_the_same_union_as_with_transform(hf_dataset, noisy):
    """The recipe's other spelling: ``set_transform`` formats in place (on a copy here, the fixture is shared)."""
    in_place = hf_dataset.select(range(ITEMS))
    in_place.set_transform(to_rgb_tensors)
    union = DegradedDataset(in_place, noisy, policy=Union(), seed=2)
    expected = DegradedDataset(hf_dataset.with_transform(to_rgb_tensors), noisy, policy=Union(), seed=2)
    assert len(union) == len(expected) == 2 * ITEMS
    assert all(torch.equal(a["image"], b["image"]) for a, b in zip(union, expected))


def test_bytes_do_not_depend_on_workers_or_shuffling(hf_dataset, noisy):
    union = DegradedDataset(hf_dataset.with_transform(to_rgb_tensors), noisy, policy="union", seed=3)
    expected = sorted((union[j]["index"], digest(union[j]["image"])) for j in range(len(union)))
    loader = DataLoader(union, batch_size=4, shuffle=True, num_workers=2)
    seen = sorted(
        (int(index), digest(image)) for batch in loader for index, image in zip(batch["index"], batch["image"])
    )
    assert seen == expected


def test_pil_rows_and_a_final_transform(hf_dataset, noisy):
    final = v2.Compose([v2.ToImage(), v2.ToDtype(torch.float32, scale=True)])
    union = DegradedDataset(hf_dataset.with_transform(to_rgb_pil), noisy, policy="union", seed=0, transform=final)
    clean, degraded = union[0], union[1]
    assert clean["image"].shape == (3, 10, 14) and clean["image"].dtype == torch.float32
    assert clean["label"] == degraded["label"] == 0
    assert not torch.equal(clean["image"], degraded["image"])


def test_with_format_torch_rows_when_they_are_chw(hf_dataset, noisy):
    rgb = datasets.Dataset.from_dict({"image": [row["image"].convert("RGB") for row in hf_dataset], "label": [0] * 6})
    formatted = rgb.with_format("torch")
    if formatted[0]["image"].shape[0] != 3:
        pytest.skip("this datasets version formats images as (H, W, C); use with_transform")
    union = DegradedDataset(formatted, noisy, policy="union", seed=0)
    assert torch.equal(union[0]["image"], formatted[0]["image"])
    assert union[1]["image"].shape == (3, 10, 14) and not torch.equal(union[1]["image"], union[0]["image"])


def test_streaming_dataset_with_an_index_column_matches_the_map_style_union(hf_dataset, noisy):
    stream = hf_dataset.to_iterable_dataset().map(to_rgb_tensors, batched=True)
    with pytest.raises(TypeError, match="DegradedIterableDataset"):
        DegradedDataset(stream, noisy)
    streamed = DegradedIterableDataset(stream, noisy, policy="union", seed=0, index_of=operator.itemgetter("index"))
    mapped = DegradedDataset(hf_dataset.with_transform(to_rgb_tensors), noisy, policy="union", seed=0)
    streamed_images = [item["image"] for item in streamed]
    assert len(streamed_images) == len(mapped) == 2 * ITEMS
    assert all(torch.equal(a, mapped[j]["image"]) for j, a in enumerate(streamed_images))


def test_rows_in_numpy_format_are_degraded_as_numpy(noisy):
    """``with_format("numpy")`` rows hold HWC uint8 arrays; before, their 'degraded' view was the clean bytes."""
    rgb = datasets.Dataset.from_dict(
        {
            "image": [
                PIL.Image.fromarray(np.random.default_rng(i).integers(0, 256, (10, 14, 3), dtype=np.uint8))
                for i in range(3)
            ],
            "label": [0, 1, 2],
        }
    ).with_format("numpy")
    union = DegradedDataset(rgb, noisy, policy=Union(), seed=0)
    for source_index in range(3):
        clean, degraded = union[2 * source_index], union[2 * source_index + 1]
        assert isinstance(degraded["image"], np.ndarray) and degraded["image"].dtype == np.uint8
        assert degraded["image"].shape == clean["image"].shape == (10, 14, 3)
        assert not np.array_equal(degraded["image"], clean["image"])
        assert degraded["label"] == clean["label"] == source_index
