"""DegradedDataset, mixing policies and BatchDegrade: exact decisions, structure, replay, errors."""

from __future__ import annotations

import pickle
from pathlib import Path

import PIL.Image
import pytest
import torch
from torch.utils.data import IterableDataset
from torchvision import tv_tensors

from camdegrade import CameraDegrade
from camdegrade.data import (
    Alternate,
    BatchDegrade,
    Bernoulli,
    DegradedDataset,
    DegradedIterableDataset,
    IndexedDataset,
    PairedViews,
    Ratio,
    Schedule,
    Union,
    item_uniform,
    stable_key,
)
from datasets_for_tests import TinyImages, TinyStream, tiny_image
from profiles_for_tests import deterministic_profile, stochastic_profile


@pytest.fixture(scope="module")
def noisy() -> CameraDegrade:
    return CameraDegrade(stochastic_profile())


def degraded_flags(dataset: DegradedDataset) -> list[bool]:
    """Which returned images differ from their clean source, read from the data itself."""
    return [not torch.equal(dataset[j][0], dataset.dataset[dataset.source_index(j)][0]) for j in range(len(dataset))]


# --- stable keys -------------------------------------------------------------------------------------------------


def test_stable_key_is_a_fixed_formula():
    # Pinned values: a change here changes every user's decisions and degradations.
    assert stable_key(0) == 0xE220A8397B1DCDAF
    assert stable_key(1, 2, 3) == stable_key(1, 2, 3) != stable_key(1, 3, 2)
    assert stable_key(-1) == stable_key(2**64 - 1)
    assert 0.0 <= item_uniform(7, 0, 5) < 1.0


# --- policies: exactly which items are degraded ----------------------------------------------------------------


def test_union_doubles_length_and_degrades_odd_indices(noisy):
    source = TinyImages(5, size=8)
    dataset = DegradedDataset(source, noisy, policy=Union(), seed=0)
    assert len(dataset) == 10
    assert degraded_flags(dataset) == [False, True] * 5
    for j in range(10):
        assert dataset[j][1] == source[j // 2][1]
    assert torch.equal(dataset[3][0], dataset.degrade_sample(source[1], 1)[0])


def test_union_is_the_default_and_names_resolve(noisy):
    assert DegradedDataset(TinyImages(2), noisy, seed=0).policy == Union()
    assert DegradedDataset(TinyImages(2), noisy, policy="pair", seed=0).policy == PairedViews()
    assert DegradedDataset(TinyImages(2), noisy, policy="Alternate", seed=0).policy == Alternate()


def test_pair_returns_clean_and_degraded_views(noisy):
    source = TinyImages(3, size=8)
    dataset = DegradedDataset(source, noisy, policy=PairedViews(), seed=0)
    assert len(dataset) == 3
    clean, degraded = dataset[2]
    assert torch.equal(clean[0], source[2][0])
    assert clean[1] == degraded[1] == 2
    assert torch.equal(degraded[0], dataset.degrade_sample(source[2], 2)[0])
    assert not torch.equal(degraded[0], clean[0])


def test_bernoulli_decisions_follow_the_documented_rule():
    policy = Bernoulli(0.3)
    decisions = [policy.decide(i, 0, 4, 11) for i in range(20_000)]
    assert decisions == [item_uniform(11, 4, i) < 0.3 for i in range(20_000)]
    fraction = sum(decisions) / len(decisions)
    assert abs(fraction - 0.3) < 4 * (0.3 * 0.7 / 20_000) ** 0.5
    assert not any(Bernoulli(0.0).decide(i, 0, 0, 0) for i in range(1000))
    assert all(Bernoulli(1.0).decide(i, 0, 0, 0) for i in range(1000))
    assert decisions != [policy.decide(i, 0, 5, 11) for i in range(20_000)]  # fresh draws each epoch


def test_bernoulli_degrades_exactly_the_decided_items(noisy):
    dataset = DegradedDataset(TinyImages(8, size=8), noisy, policy=Bernoulli(0.5), seed=2)
    assert degraded_flags(dataset) == [dataset.decision(i) for i in range(8)]


@pytest.mark.parametrize(("k", "m"), [(0, 3), (1, 3), (2, 3), (3, 3), (1, 4)])
def test_ratio_is_exact_per_block_and_per_item_over_epochs(k, m):
    policy = Ratio(k, m)
    for epoch in range(m):
        decisions = [policy.decide(i, 0, epoch, 0) for i in range(6 * m)]
        for block in range(6):
            assert sum(decisions[block * m : (block + 1) * m]) == k
    for index in range(2 * m):
        assert sum(policy.decide(index, 0, epoch, 0) for epoch in range(m)) == k


def test_ratio_pattern_on_data(noisy):
    dataset = DegradedDataset(TinyImages(6, size=8), noisy, policy=Ratio(1, 3), seed=0)
    assert degraded_flags(dataset) == [True, False, False] * 2
    dataset.set_epoch(1)
    assert degraded_flags(dataset) == [False, False, True] * 2


def test_alternate_degrades_half_and_flips_every_epoch(noisy):
    dataset = DegradedDataset(TinyImages(6, size=8), noisy, policy=Alternate(), seed=0)
    assert degraded_flags(dataset) == [False, True] * 3
    dataset.set_epoch(1)
    assert degraded_flags(dataset) == [True, False] * 3


def test_schedule_uses_the_epochs_probability():
    schedule = Schedule([0.0, 1.0, 0.25])
    assert not any(schedule.decide(i, 0, 0, 3) for i in range(500))
    assert all(schedule.decide(i, 0, 1, 3) for i in range(500))
    assert [schedule.decide(i, 0, 9, 3) for i in range(500)] == [Bernoulli(0.25).decide(i, 0, 9, 3) for i in range(500)]
    assert [Schedule.linear(0.0, 1.0, epochs=5).probability(e) for e in range(7)] == [0, 0.25, 0.5, 0.75, 1, 1, 1]
    assert Schedule(_half).probability(3) == 0.5


def _half(epoch: int) -> float:
    return 0.5


def test_policies_pickle_and_compare():
    for policy in (
        Union(),
        PairedViews(),
        Bernoulli(0.2),
        Alternate(),
        Ratio(2, 5),
        Schedule([0.1, 0.2]),
        Schedule(_half),
    ):
        assert pickle.loads(pickle.dumps(policy)) == policy
        assert type(policy).__name__ in repr(policy)


# --- determinism of the values -------------------------------------------------------------------------------------


def test_same_seed_same_bytes_other_seed_or_epoch_differs(noisy):
    first = DegradedDataset(TinyImages(2), noisy, seed=5)
    second = DegradedDataset(TinyImages(2), CameraDegrade(stochastic_profile()), seed=5)
    assert torch.equal(first[1][0], second[1][0])
    assert torch.equal(first[1][0], first[1][0])
    assert not torch.equal(first[1][0], DegradedDataset(TinyImages(2), noisy, seed=6)[1][0])
    second.set_epoch(1)
    assert second.epoch == 1
    assert not torch.equal(first[1][0], second[1][0])


def test_seed_none_draws_from_torch_global_rng(noisy):
    torch.manual_seed(0)
    first = DegradedDataset(TinyImages(2), noisy).seed
    torch.manual_seed(0)
    assert DegradedDataset(TinyImages(2), noisy).seed == first


def test_pickled_dataset_gives_the_same_bytes(noisy):
    dataset = DegradedDataset(TinyImages(3), noisy, policy=Bernoulli(0.5), seed=1)
    dataset.set_epoch(2)
    copy = pickle.loads(pickle.dumps(dataset))
    assert copy.epoch == 2
    for j in range(3):
        assert torch.equal(copy[j][0], dataset[j][0])


# --- structure -----------------------------------------------------------------------------------------------------


def test_dict_sample_structure_and_untouched_items(noisy):
    image = tv_tensors.Image(tiny_image(0, 12))
    boxes = tv_tensors.BoundingBoxes([[1, 2, 5, 6]], format="XYXY", canvas_size=(12, 12))
    mask = tv_tensors.Mask(torch.zeros(12, 12, dtype=torch.uint8))
    sample = {"image": image, "boxes": boxes, "mask": mask, "label": 3, "name": "x", "none": None, "path": Path("p")}
    dataset = DegradedDataset([sample], noisy, policy=PairedViews(), seed=0)
    clean, degraded = dataset[0]
    assert clean is sample
    assert degraded.keys() == sample.keys()
    assert type(degraded["image"]) is tv_tensors.Image
    assert not torch.equal(degraded["image"], image)
    for key in ("boxes", "mask", "label", "name", "none", "path"):
        assert degraded[key] is sample[key]


def test_degraded_views_move_their_targets_with_the_image():
    """A profile that moves pixels moves the degraded view's mask and boxes too; the clean view keeps its own."""
    from camdegrade import CameraProfile
    from camdegrade.effects import Misalignment

    image = torch.full((3, 24, 32), 0.15)
    image[:, 8:16, 10:18] = 0.85
    mask = tv_tensors.Mask((image[0] > 0.5).to(torch.uint8))
    boxes = tv_tensors.BoundingBoxes([[10.0, 8.0, 18.0, 16.0]], format="XYXY", canvas_size=(24, 32))
    sample = {"image": tv_tensors.Image(image), "mask": mask, "boxes": boxes}
    shifted = CameraProfile(None, [Misalignment(3.0, 2.0)], name="shifted")  # whole pixels: exact
    dataset = DegradedDataset([sample], shifted, policy=PairedViews(), seed=0)
    clean, degraded = dataset[0]
    assert clean is sample
    moved = degraded["image"][0] > 0.5
    assert torch.equal(degraded["mask"].bool(), moved) and not torch.equal(degraded["mask"], mask)
    ys, xs = moved.nonzero(as_tuple=True)
    found = torch.tensor([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1], dtype=torch.float32)
    torch.testing.assert_close(degraded["boxes"][0], found, atol=1e-4, rtol=0)


def test_pil_tuple_sample_comes_back_as_pil(noisy):
    pil = PIL.Image.fromarray(tiny_image(0, 10).permute(1, 2, 0).numpy())
    image, target = DegradedDataset([(pil, {"id": 1})], noisy, policy=Union(), seed=0)[1]
    assert isinstance(image, PIL.Image.Image) and image.size == pil.size
    assert target == {"id": 1}


def test_transform_applies_to_every_view(noisy):
    dataset = DegradedDataset(
        TinyImages(2), noisy, policy=PairedViews(), seed=0, transform=lambda s: (s[0].float(), s[1])
    )
    clean, degraded = dataset[0]
    assert clean[0].dtype == degraded[0].dtype == torch.float32


def test_wrapper_delegates_attributes_and_indexing(noisy):
    dataset = DegradedDataset(TinyImages(3), noisy, seed=0)
    assert dataset.classes == ["a", "b", "c"]
    assert torch.equal(dataset[-1][0], dataset[5][0])
    with pytest.raises(IndexError, match="out of range"):
        dataset[6]
    with pytest.raises(AttributeError):
        dataset.missing_attribute  # noqa: B018
    assert "Union()" in repr(dataset) and "seed=0" in repr(dataset)


def test_degrade_may_be_a_profile():
    dataset = DegradedDataset(TinyImages(1), deterministic_profile(), seed=0)
    assert isinstance(dataset.degrade, CameraDegrade)
    assert not torch.equal(dataset[1][0], dataset[0][0])


def test_indexed_dataset():
    indexed = IndexedDataset(TinyImages(2))
    index, (image, label) = indexed[1]
    assert index == 1 and label == 1 and torch.equal(image, tiny_image(1))
    assert len(indexed) == 2 and indexed.classes == ["a", "b", "c"]


# --- iterable variant ----------------------------------------------------------------------------------------------


def test_iterable_union_matches_map_style(noisy):
    stream = DegradedIterableDataset(TinyStream(3), noisy, policy=Union(), seed=4)
    mapped = DegradedDataset(TinyImages(3, as_dict=True), noisy, policy=Union(), seed=4)
    items = list(stream)
    assert len(items) == 6
    for j, item in enumerate(items):
        assert item["index"] == j // 2
        assert torch.equal(item["image"], mapped[j]["image"])


def test_iterable_index_of_keys_decisions(noisy):
    samples = [{"image": tiny_image(i), "index": i} for i in (5, 9)]
    stream = DegradedIterableDataset(samples, noisy, Bernoulli(0.5), seed=1, index_of=lambda s: s["index"])
    mapped = DegradedDataset([None] * 10, noisy, Bernoulli(0.5), seed=1)
    for item in stream:
        reference = mapped.degrade_sample(item, item["index"]) if mapped.decision(item["index"]) else item
        assert torch.equal(item["image"], reference["image"])


# --- BatchDegrade --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("dtype", [torch.uint8, torch.float32])
def test_batch_degrade_equals_the_per_sample_path(dtype):
    source = TinyImages(9)
    per_sample = DegradedDataset(source, stochastic_profile(), policy=Bernoulli(0.5), seed=3)
    batch_degrade = BatchDegrade(stochastic_profile(), p=0.5, seed=3)
    indices = torch.tensor([7, 0, 3, 8, 1, 5])
    for epoch in (0, 1):
        per_sample.set_epoch(epoch)
        images = torch.stack([source[i][0] for i in indices.tolist()])
        expected = torch.stack([per_sample[i][0] for i in indices.tolist()])
        if dtype == torch.float32:
            images, expected = images / 255, expected / 255
        out = batch_degrade(images.to(dtype), indices, epoch=epoch)
        assert out.dtype == images.dtype and out.shape == images.shape
        decided = torch.tensor([per_sample.decision(i) for i in indices.tolist()])
        assert 0 < int(decided.sum()) < len(indices)
        assert torch.equal(out[~decided], images[~decided])
        # Within one 8-bit level: batched vs single-image arithmetic (bfloat16 where native) can round differently.
        if dtype == torch.uint8:
            assert (out.int() - expected.int()).abs().max() <= 1
        else:
            assert ((out * 255).round() - (expected * 255).round()).abs().max() <= 1


def test_batch_degrade_policies_epochs_and_index_numbering():
    images = torch.stack([tiny_image(i) for i in range(4)])
    alternate = BatchDegrade(deterministic_profile(), p=Alternate(), seed=0)
    changed = (alternate(images, [0, 1, 2, 3], epoch=0) != images).flatten(1).any(1)
    assert changed.tolist() == [False, True, False, True]
    numbered = BatchDegrade(stochastic_profile(), p=1.0, seed=0)
    first = numbered(images)
    second = numbered(images)
    assert torch.equal(second, numbered(images, indices=[4, 5, 6, 7]))
    assert not torch.equal(first, second)
    numbered.set_epoch(0)
    assert torch.equal(numbered(images), first)
    assert numbered(images[:0]).shape == (0, 3, 16, 16)


def test_batch_degrade_errors():
    with pytest.raises(ValueError, match="one-view policy"):
        BatchDegrade(deterministic_profile(), p=Union())
    with pytest.raises(ValueError, match="one-view policy"):
        BatchDegrade(deterministic_profile(), p=PairedViews())
    batch_degrade = BatchDegrade(deterministic_profile(), p=0.5, seed=0)
    with pytest.raises(ValueError, match="one integer dataset index per image"):
        batch_degrade(torch.zeros(2, 3, 4, 4), [0])
    with pytest.raises(ValueError, match=r"\(B, 3, H, W\)"):
        batch_degrade(torch.zeros(3, 4, 4))
    with pytest.raises(ValueError, match="p must be a probability"):
        BatchDegrade(deterministic_profile(), p=1.5)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_batch_degrade_on_cuda_matches_cpu():
    images = torch.stack([tiny_image(i) for i in range(6)])
    batch_degrade = BatchDegrade(stochastic_profile(), p=0.5, seed=3)
    on_cpu = batch_degrade(images, torch.arange(6), epoch=2)
    on_gpu = batch_degrade(images.cuda(), torch.arange(6), epoch=2)
    assert on_gpu.device.type == "cuda"
    assert (on_gpu.cpu().int() - on_cpu.int()).abs().max() <= 1


# --- argument errors -----------------------------------------------------------------------------------------------


def test_argument_errors(noisy):
    with pytest.raises(ValueError, match="policy must be a MixPolicy"):
        DegradedDataset(TinyImages(1), noisy, policy="sometimes")
    with pytest.raises(ValueError, match="k must be at most m"):
        Ratio(3, 2)
    with pytest.raises(ValueError, match="m must be an integer >= 1"):
        Ratio(0, 0)
    with pytest.raises(ValueError, match="p must be a probability"):
        Bernoulli(-0.1)
    with pytest.raises(TypeError, match="p must be a non-empty sequence"):
        Schedule([])
    with pytest.raises(TypeError, match="seed must be an int"):
        DegradedDataset(TinyImages(1), noisy, seed="1")
    with pytest.raises(TypeError, match="degrade must be a CameraDegrade"):
        DegradedDataset(TinyImages(1), 3)
    with pytest.raises(TypeError, match="DegradedIterableDataset"):
        DegradedDataset(TinyStream(2), noisy)
    with pytest.raises(ValueError, match="epoch must be an integer >= 0"):
        DegradedDataset(TinyImages(1), noisy).set_epoch(-1)
    with pytest.raises(TypeError, match="has no length"):
        len(DegradedIterableDataset(iter([]), noisy))
    assert isinstance(DegradedIterableDataset([], noisy), IterableDataset)
