"""Train on clean + camera-degraded images with Lightning: a LightningDataModule around DegradedDataset.

Two pieces carry over to any Lightning project (``pip install 'camdegrade[lightning]'``):

1. ``DegradedDataModule`` wraps your training set in ``DegradedDataset`` (default policy ``Union()``: every image
   once clean, once degraded) and, optionally, your validation set in a ``PairedViews()`` view (each image clean and
   degraded, to report accuracy on both).
2. ``SetEpoch``, a callback, calls ``set_epoch(trainer.current_epoch)`` on the training set at every epoch start,
   so each epoch draws fresh noise, exactly as ``DistributedSampler.set_epoch`` reshuffles.

DDP needs nothing more: Lightning adds a ``DistributedSampler`` (and sets its epoch), the callback runs on every
rank with the same epoch, and the dataset's seed is an explicit integer, so every rank derives the same decisions
and noise and the ranks together see each item once clean and once degraded per epoch. Offline, on the CPU::

    .venv/bin/python examples/lightning_datamodule.py --epochs 2
    .venv/bin/python examples/lightning_datamodule.py --epochs 2 --devices 2 --strategy ddp   # two CPU ranks
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator
from typing import Any

import lightning as L
import torch
import torch.nn.functional as F
from torch.utils.data import DataLoader, Dataset
from torchvision.transforms import v2
from train_classifier import camera_profile, small_cnn

from camdegrade.data import DegradedDataset, DegradedIterableDataset, MixPolicy, PairedViews
from camdegrade.data.datasets import DegradeLike

CLASSES = 3
MEAN, STD = [0.5, 0.5, 0.5], [0.25, 0.25, 0.25]


class DegradedDataModule(L.LightningDataModule):
    """Serves ``train_source`` through :class:`DegradedDataset` (and ``val_source``, if given, as clean/degraded pairs).

    Args:
        train_source: any map-style dataset whose images are PIL, uint8 or float in ``[0, 1]`` (normalise in
            ``transform``, which runs after the camera).
        degrade: a profile name or path, a ``CameraProfile`` or a ``CameraDegrade``.
        seed: the dataset seed. An explicit integer, so every DDP rank degrades the same items the same way.
        policy: ``"union"`` (the paper) or any other ``camdegrade.data`` policy.
        transform: applied to every view after degradation, e.g. ``ToDtype`` + ``Normalize``.
        val_source: optional validation set, returned as ``(clean, degraded)`` pairs (epoch 0's noise, fixed).
    """

    def __init__(
        self,
        train_source: Dataset,
        degrade: DegradeLike,
        seed: int,
        policy: MixPolicy | str = "union",
        transform: Callable[[Any], Any] | None = None,
        val_source: Dataset | None = None,
        batch_size: int = 32,
        num_workers: int = 0,
    ) -> None:
        super().__init__()
        if isinstance(seed, bool) or not isinstance(seed, int):
            raise TypeError(f"seed must be an int (the same on every rank), got seed={seed!r}")
        self.train_set = DegradedDataset(train_source, degrade, policy=policy, seed=seed, transform=transform)
        self.val_set = None
        if val_source is not None:
            self.val_set = DegradedDataset(
                val_source, self.train_set.degrade, PairedViews(), seed=seed + 1, transform=transform
            )
            # Only a module with a validation set offers val_dataloader (as LightningDataModule.from_datasets does),
            # so that without one Lightning skips validation instead of warning about an empty loader.
            self.val_dataloader = self._val_dataloader
        self.batch_size = batch_size
        self.num_workers = num_workers

    def train_dataloader(self) -> DataLoader:
        # Lightning creates the first epoch's iterator (which already loads items) before on_train_epoch_start, and
        # a run resumed from a checkpoint starts at a later epoch: so set the epoch here as well as in SetEpoch.
        self.train_set.set_epoch(self.trainer.current_epoch if self.trainer is not None else 0)
        return self._loader(self.train_set, shuffle=True)

    def _val_dataloader(self) -> DataLoader:
        return self._loader(self.val_set, shuffle=False)

    def _loader(self, dataset: Dataset, shuffle: bool) -> DataLoader:
        # shuffle=True also separates an item's two views; under DDP Lightning swaps in a DistributedSampler.
        workers = self.num_workers
        return DataLoader(
            dataset, self.batch_size, shuffle=shuffle, num_workers=workers, persistent_workers=workers > 0
        )


class SetEpoch(L.Callback):
    """At every training epoch start, ``set_epoch(trainer.current_epoch)`` on each camdegrade training dataset.

    Lightning calls this hook on every rank with the same epoch, after it set the samplers' epoch and before it
    creates the epoch's DataLoader iterator (from the second epoch on; see ``DegradedDataModule.train_dataloader``
    for the first). The epoch lives in shared memory, so it reaches persistent workers too.
    """

    def on_train_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        for dataset in camdegrade_datasets(trainer.train_dataloader):
            dataset.set_epoch(trainer.current_epoch)


def camdegrade_datasets(loaders: Any) -> Iterator[DegradedDataset | DegradedIterableDataset]:
    """The camdegrade datasets behind a DataLoader or a (nested) list/tuple/dict of them."""
    if isinstance(loaders, DataLoader):
        if isinstance(loaders.dataset, (DegradedDataset, DegradedIterableDataset)):
            yield loaders.dataset
    elif isinstance(loaders, dict):
        for loader in loaders.values():
            yield from camdegrade_datasets(loader)
    elif isinstance(loaders, (list, tuple)):
        for loader in loaders:
            yield from camdegrade_datasets(loader)


class ColourSquares(Dataset):
    """``length`` synthetic ``(uint8 image (3, size, size), label)`` items: a square whose colour names the class.

    Each item is drawn from its own generator, so the data is the same in every process (workers, ranks).
    """

    def __init__(self, length: int, size: int = 24, seed: int = 0) -> None:
        self.length, self.size, self.seed = length, size, seed

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, index: int) -> tuple[torch.Tensor, int]:
        if not 0 <= index < self.length:
            raise IndexError(index)
        generator = torch.Generator().manual_seed(self.seed * 1_000_003 + index)
        label = index % CLASSES
        image = torch.randint(0, 80, (3, self.size, self.size), dtype=torch.uint8, generator=generator)
        side = int(torch.randint(self.size // 3, self.size - 2, (), generator=generator))
        top, left = (int(v) for v in torch.randint(0, self.size - side + 1, (2,), generator=generator))
        colour = torch.randint(0, 100, (3, 1, 1), generator=generator)
        colour[label] += 155
        image[:, top : top + side, left : left + side] = colour.to(torch.uint8)
        return image, label


class Classifier(L.LightningModule):
    """The small CNN of ``train_classifier.py`` (this folder); validation reports accuracy on clean and on
    camera-degraded images."""

    def __init__(self, classes: int = CLASSES, lr: float = 3e-3) -> None:
        super().__init__()
        self.lr = lr
        self.net = small_cnn(classes)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.net(images)

    def training_step(self, batch: tuple[torch.Tensor, torch.Tensor], batch_idx: int) -> torch.Tensor:
        images, labels = batch
        loss = F.cross_entropy(self(images), labels)
        self.log("train_loss", loss, on_step=False, on_epoch=True, batch_size=len(labels), sync_dist=True)
        return loss

    def validation_step(self, batch: tuple[Any, Any], batch_idx: int) -> None:
        for name, (images, labels) in zip(("clean", "camera"), batch):  # PairedViews(): (clean view, degraded view)
            accuracy = (self(images).argmax(1) == labels).float().mean()
            self.log(f"val_accuracy_{name}", accuracy, batch_size=len(labels), sync_dist=True)

    def configure_optimizers(self) -> torch.optim.Optimizer:
        return torch.optim.Adam(self.parameters(), lr=self.lr)


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", default=None, help="profile name or .safetensors path (default: city100-iphonex)")
    parser.add_argument("--epochs", type=int, default=4)
    parser.add_argument("--items", type=int, default=96, help="training images (the union serves twice as many)")
    parser.add_argument("--batch-size", type=int, default=16)
    parser.add_argument("--workers", type=int, default=0)
    parser.add_argument("--devices", type=int, default=1)
    parser.add_argument("--strategy", default="auto", help="e.g. ddp for several CPU processes")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="out/lightning", help="Lightning's default_root_dir")
    args = parser.parse_args(argv)

    L.seed_everything(args.seed, verbose=False)  # the model's initial weights and the loader's shuffling
    normalize = v2.Compose([v2.ToDtype(torch.float32, scale=True), v2.Normalize(MEAN, STD)])
    data = DegradedDataModule(
        ColourSquares(args.items, seed=args.seed),
        camera_profile(args.profile),
        seed=args.seed,
        transform=normalize,
        val_source=ColourSquares(max(args.items // 2, 1), seed=args.seed + 1),
        batch_size=args.batch_size,
        num_workers=args.workers,
    )
    trainer = L.Trainer(
        max_epochs=args.epochs,
        accelerator="cpu",
        devices=args.devices,
        strategy=args.strategy,
        callbacks=[SetEpoch()],
        default_root_dir=args.out,
        logger=False,
        enable_checkpointing=False,
        enable_model_summary=False,
        enable_progress_bar=False,
        num_sanity_val_steps=0,
    )
    trainer.fit(Classifier(), datamodule=data)
    metrics = {name: float(value) for name, value in trainer.callback_metrics.items()}
    if trainer.is_global_zero:
        print(", ".join(f"{name} {value:.3f}" for name, value in sorted(metrics.items())))
    return metrics


if __name__ == "__main__":
    main()
