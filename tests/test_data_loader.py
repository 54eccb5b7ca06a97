"""Determinism of DegradedDataset under DataLoader workers, persistent workers, shuffling and DistributedSampler."""

from __future__ import annotations

import json
from multiprocessing.reduction import ForkingPickler
from pathlib import Path

import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp
from torch.utils.data import DataLoader, DistributedSampler

from camdegrade.data import Bernoulli, DegradedDataset, DegradedIterableDataset, Union
from datasets_for_tests import TinyImages, TinyStream, digest
from profiles_for_tests import stochastic_profile

LENGTH = 8


def make_dataset(policy=None) -> DegradedDataset:
    return DegradedDataset(TinyImages(LENGTH, as_dict=True), stochastic_profile(), policy or Union(), seed=13)


def reference(dataset: DegradedDataset, epoch: int) -> list[tuple[int, str]]:
    """(source index, image digest) of every item of ``epoch``, computed in this process, sorted."""
    copy = make_dataset(dataset.policy)
    copy.set_epoch(epoch)
    return sorted((copy[j]["index"], digest(copy[j]["image"])) for j in range(len(copy)))


def loaded(loader: DataLoader) -> list[tuple[int, str]]:
    return sorted(
        (int(index), digest(image)) for batch in loader for index, image in zip(batch["index"], batch["image"])
    )


@pytest.mark.parametrize(
    ("workers", "persistent", "shuffle"), [(0, False, False), (2, False, True), (2, True, True)], ids=str
)
def test_identical_bytes_for_any_worker_setup(workers, persistent, shuffle):
    dataset = make_dataset(Bernoulli(0.5))
    loader = DataLoader(
        dataset,
        batch_size=3,
        shuffle=shuffle,
        num_workers=workers,
        persistent_workers=persistent,
        generator=torch.Generator().manual_seed(0),
    )
    per_epoch = []
    for epoch in (0, 1, 2):
        dataset.set_epoch(epoch)
        items = loaded(loader)
        assert items == reference(dataset, epoch)
        per_epoch.append(items)
    assert per_epoch[0] != per_epoch[1] != per_epoch[2]  # the epoch reached the workers


def test_epoch_is_shared_with_workers_that_receive_a_pickled_dataset():
    # Spawned and forkserver workers get the dataset through torch's multiprocessing pickler, which shares tensor
    # memory instead of copying it: set_epoch in the main process must reach that copy too. (A full DataLoader with
    # multiprocessing_context="spawn" passes as well, but starting fresh interpreters takes ~30 s here.)
    dataset = make_dataset(Union())
    copy = ForkingPickler.loads(ForkingPickler.dumps(dataset))
    dataset.set_epoch(5)
    assert copy.epoch == 5
    assert torch.equal(copy[1]["image"], dataset[1]["image"])


def test_iterable_round_robin_shards_match_map_style():
    stream = DegradedIterableDataset(TinyStream(LENGTH), stochastic_profile(), Union(), seed=13)
    stream.set_epoch(1)
    loader = DataLoader(stream, batch_size=2, num_workers=2)
    assert loaded(loader) == reference(make_dataset(Union()), 1)


def _rank_main(rank: int, world_size: int, store: str, out_dir: str) -> None:
    torch.set_num_threads(1)
    dist.init_process_group("gloo", init_method=f"file://{store}", rank=rank, world_size=world_size)
    try:
        dataset = make_dataset(Bernoulli(0.5))
        sampler = DistributedSampler(dataset, shuffle=True, seed=7)
        records = []
        for epoch in (0, 1):
            sampler.set_epoch(epoch)
            dataset.set_epoch(epoch)
            for index in sampler:
                image = dataset[index]["image"]
                records.append([epoch, index, bool(dataset.decision(index)), digest(image)])
        Path(out_dir, f"rank{rank}.json").write_text(json.dumps(records))
        dist.barrier()
    finally:
        dist.destroy_process_group()


def test_two_rank_distributed_sampler(tmp_path):
    # Two real processes in a gloo group (file:// rendezvous, no network); forked so they skip re-importing torch.
    mp.start_processes(
        _rank_main, args=(2, str(tmp_path / "store"), str(tmp_path)), nprocs=2, start_method="fork", join=True
    )
    ranks = [json.loads((tmp_path / f"rank{rank}.json").read_text()) for rank in range(2)]
    dataset = make_dataset(Bernoulli(0.5))
    for epoch in (0, 1):
        shards = [{index for e, index, _, _ in records if e == epoch} for records in ranks]
        assert shards[0].isdisjoint(shards[1])
        assert shards[0] | shards[1] == set(range(LENGTH))
        dataset.set_epoch(epoch)
        for records in ranks:
            for e, index, decision, image_digest in records:
                if e == epoch:
                    assert decision == dataset.decision(index)
                    assert image_digest == digest(dataset[index]["image"])
    decisions = [decision for records in ranks for _, _, decision, _ in records]
    assert 0 < sum(decisions) < len(decisions)
