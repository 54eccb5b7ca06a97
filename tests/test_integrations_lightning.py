"""``examples/lightning_datamodule.py`` under a real Lightning Trainer (CPU); skipped when Lightning is absent.

What the model sees each epoch is recorded and compared with a DegradedDataset built separately with the same seed:
the trainer's epoch reaches the dataset (and its persistent workers), the union's counts hold, and the bytes match.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections import Counter
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

L = pytest.importorskip("lightning")

from conftest import load_script  # noqa: E402
from profiles_for_tests import stochastic_profile  # noqa: E402

pytestmark = [
    # Lightning's advice (more workers, the GPU it saw but was told not to use) depends on the machine, not on us.
    pytest.mark.filterwarnings("ignore::lightning.fabric.utilities.warnings.PossibleUserWarning"),
    # lightning 2.6 builds torch pytree LeafSpec objects, which recent torch deprecates.
    pytest.mark.filterwarnings("ignore:.*LeafSpec.*is deprecated:FutureWarning"),
]

ITEMS = 12  # source images; the union serves 24 per epoch
EPOCHS = 2


example = load_script("examples/lightning_datamodule.py", "lightning_datamodule")


@pytest.fixture(autouse=True)
def restore_environment():
    """Lightning leaves variables behind in os.environ (MASTER_PORT after DDP, ...): later tests must not see them."""
    saved = dict(os.environ)
    yield
    os.environ.clear()
    os.environ.update(saved)


class IndexedSquares(example.ColourSquares):
    """``(image, label, index)``: the index passes through DegradedDataset untouched, so the test can follow items."""

    def __getitem__(self, index: int):
        return (*super().__getitem__(index), index)


class Recorder(example.Classifier):
    """Trains like the example's classifier and records ``(epoch, source index, image digest)`` for every sample."""

    def __init__(self, out_dir: Path) -> None:
        super().__init__()
        self.out_dir = out_dir
        self.records: list[tuple[int, int, str]] = []

    def training_step(self, batch, batch_idx):
        images, labels, indices = batch
        self.records += [(self.current_epoch, int(i), digest(image)) for i, image in zip(indices, images)]
        return F.cross_entropy(self(images), labels)

    def on_train_end(self) -> None:
        (self.out_dir / f"rank{self.global_rank}.json").write_text(json.dumps(self.records))


def digest(image: torch.Tensor) -> str:
    return hashlib.sha256(image.contiguous().numpy().tobytes()).hexdigest()[:16]


def data_module(workers: int = 0):
    to_float = example.v2.ToDtype(torch.float32, scale=True)  # a transform after the camera, as in the example
    return example.DegradedDataModule(
        IndexedSquares(ITEMS, size=16),
        stochastic_profile(),
        seed=5,
        transform=to_float,
        batch_size=5,
        num_workers=workers,
    )


def fit(tmp_path: Path, workers: int = 0, epochs: int = EPOCHS, ckpt_path: Path | None = None, **trainer_args):
    """Fit the recording model; returns each rank's records and the trainer."""
    trainer = L.Trainer(
        max_epochs=epochs,
        accelerator="cpu",
        callbacks=[example.SetEpoch()],
        default_root_dir=tmp_path,
        logger=False,
        enable_checkpointing=False,
        enable_model_summary=False,
        enable_progress_bar=False,
        **trainer_args,
    )
    trainer.fit(Recorder(tmp_path), datamodule=data_module(workers), ckpt_path=ckpt_path)
    records = [[tuple(r) for r in json.loads(path.read_text())] for path in sorted(tmp_path.glob("rank*.json"))]
    return records, trainer


def reference(epoch: int) -> tuple[list[tuple[int, str]], list[str]]:
    """From a separately built module with the same seed: every (source index, digest) served in ``epoch``, and the
    clean digests by source index."""
    train_set = data_module().train_set
    train_set.set_epoch(epoch)
    served = sorted((train_set.source_index(j), digest(train_set[j][0])) for j in range(len(train_set)))
    clean = [digest(train_set.transform(train_set.dataset[i][0])) for i in range(ITEMS)]
    return served, clean


def check_epoch(records: list[tuple[int, int, str]], epoch: int) -> dict[int, str]:
    """Checks what was served in ``epoch``; returns the degraded digest of each source index."""
    seen = sorted((index, image) for e, index, image in records if e == epoch)
    served, clean = reference(epoch)
    assert seen == served  # same seed, same bytes, whatever process or rank loaded them
    assert Counter(index for index, _ in seen) == dict.fromkeys(range(ITEMS), 2)  # each item twice ...
    for index in range(ITEMS):  # ... once clean and once degraded: half and half
        assert sorted(image == clean[index] for i, image in seen if i == index) == [False, True]
    return {index: image for index, image in seen if image != clean[index]}


def check_union(records: list[tuple[int, int, str]]) -> None:
    degraded = [check_epoch(records, epoch) for epoch in range(EPOCHS)]
    # The trainer's epoch reached the dataset: epoch 1 drew fresh noise for every degraded view.
    assert all(degraded[0][i] != degraded[1][i] for i in range(ITEMS))


def test_fit_sets_the_epoch_and_serves_the_union(tmp_path):
    # Two persistent workers: they are started in epoch 0, so epoch 1 must reach them through shared memory.
    [records], _ = fit(tmp_path, workers=2, devices=1)
    assert len(records) == EPOCHS * 2 * ITEMS
    check_union(records)


def test_resumed_fit_serves_the_checkpoint_epoch(tmp_path):
    # Lightning loads the first batches of a resumed run before on_train_epoch_start: train_dataloader sets the epoch.
    _, trainer = fit(tmp_path, workers=2, epochs=1, devices=1)
    trainer.save_checkpoint(tmp_path / "epoch0.ckpt")
    [records], _ = fit(tmp_path, workers=2, epochs=2, ckpt_path=tmp_path / "epoch0.ckpt", devices=1)
    assert {epoch for epoch, _, _ in records} == {1}
    check_epoch(records, 1)


def test_ddp_ranks_share_out_the_union(tmp_path):
    # Two CPU ranks (gloo), forked from this process: Lightning adds a DistributedSampler and sets its epoch.
    ranks, _ = fit(tmp_path, devices=2, strategy="ddp_fork")
    assert len(ranks) == 2 and all(len(records) == EPOCHS * ITEMS for records in ranks)
    for epoch in range(EPOCHS):
        shards = [{(index, image) for e, index, image in records if e == epoch} for records in ranks]
        assert shards[0].isdisjoint(shards[1])
    check_union(ranks[0] + ranks[1])


def test_example_main_runs(tmp_path, capsys):
    metrics = example.main(["--epochs", "1", "--items", "12", "--batch-size", "6", "--out", str(tmp_path)])
    assert {"train_loss", "val_accuracy_clean", "val_accuracy_camera"} <= set(metrics)
    assert "val_accuracy_camera" in capsys.readouterr().out
