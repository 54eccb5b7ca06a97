"""Train a small classifier on clean + camera-degraded images (Hegde et al.'s recipe), offline, in a minute on CPU.

An ImageFolder-style dataset is generated on the fly (three colour classes of random shapes), then a standard
torchvision training loop is changed in a few lines, each marked ``# camdegrade``:

1. wrap the training set in ``DegradedDataset`` (policy ``Union()``: every image once clean, once degraded);
2. move normalisation after the degradation (the degradation expects images in [0, 1] or uint8);
3. call ``set_epoch`` once per epoch, like ``DistributedSampler.set_epoch``.

``--batch-path`` shows the alternative: a bare loader returning indices, then ``BatchDegrade`` on the batch's
device. Run from the repo root::

    .venv/bin/python examples/train_classifier.py --epochs 4
    .venv/bin/python examples/train_classifier.py --batch-path --device cuda
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import PIL.Image
import PIL.ImageDraw
import torch
from torch import nn
from torch.utils.data import DataLoader
from torchvision.datasets import ImageFolder
from torchvision.transforms import v2

from camdegrade import CameraDegrade, CameraProfile, DomainShiftNet, load_profile
from camdegrade.data import BatchDegrade, Bernoulli, DegradedDataset, IndexedDataset, Union
from camdegrade.errors import ProfileError

CLASSES = ("red", "green", "blue")
MEAN, STD = [0.5, 0.5, 0.5], [0.25, 0.25, 0.25]


def make_image_folder(root: Path, per_class: int, size: int = 32, seed: int = 0) -> Path:
    """Write ``root/<class>/<n>.png``: a random shape (disc, square or triangle) on a dark background, with random
    size, placement and colour, except that the class's colour channel dominates the shape."""
    generator = torch.Generator().manual_seed(seed)
    for label, name in enumerate(CLASSES):
        (root / name).mkdir(parents=True, exist_ok=True)
        for n in range(per_class):
            shape, margin, background, *channels = torch.randint(0, 100, (6,), generator=generator).tolist()
            channels[label] += 155
            image = PIL.Image.new("RGB", (size, size), (background // 2,) * 3)
            draw = PIL.ImageDraw.Draw(image)
            low, high = 2 + margin % 8, size - 2 - (margin // 8) % 8
            if shape % 3 == 0:
                draw.ellipse((low, low, high, high), fill=tuple(channels))
            elif shape % 3 == 1:
                draw.rectangle((low, low, high, high), fill=tuple(channels))
            else:
                draw.polygon([(low, high), (high, high), ((low + high) // 2, low)], fill=tuple(channels))
            image.save(root / name / f"{n:03d}.png")
    return root


def camera_profile(name_or_path: str | None) -> CameraProfile:
    """The requested profile; by default the built-in City100 one, or a fixed untrained network if absent."""
    try:
        return load_profile(name_or_path or "city100-iphonex")
    except ProfileError:
        if name_or_path:
            raise
        print("note: built-in 'city100-iphonex' not found; using an untrained network as a stand-in camera")
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(0)
            return CameraProfile(DomainShiftNet(), name="untrained-stand-in")


def small_cnn(classes: int) -> nn.Module:
    return nn.Sequential(
        nn.Conv2d(3, 16, 3, padding=1),
        nn.ReLU(),
        nn.MaxPool2d(2),
        nn.Conv2d(16, 32, 3, padding=1),
        nn.ReLU(),
        nn.AdaptiveAvgPool2d(1),
        nn.Flatten(),
        nn.Linear(32, classes),
    )


def evaluate(model: nn.Module, loader: DataLoader, device: torch.device) -> float:
    model.eval()
    correct = total = 0
    with torch.no_grad():
        for images, labels in loader:
            correct += int((model(images.to(device)).argmax(1) == labels.to(device)).sum())
            total += labels.numel()
    return correct / max(total, 1)


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", default=None, help="profile name or .safetensors path (default: city100-iphonex)")
    parser.add_argument("--epochs", type=int, default=4)
    parser.add_argument("--per-class", type=int, default=24)
    parser.add_argument("--workers", type=int, default=0)
    parser.add_argument("--batch-path", action="store_true", help="degrade batches on the device with BatchDegrade")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    torch.manual_seed(args.seed)
    device = torch.device(args.device)
    profile = camera_profile(args.profile)
    normalize = v2.Compose([v2.ToDtype(torch.float32, scale=True), v2.Normalize(MEAN, STD)])

    with tempfile.TemporaryDirectory() as tmp:
        train_root = make_image_folder(Path(tmp, "train"), args.per_class, seed=args.seed)
        val_root = make_image_folder(Path(tmp, "val"), args.per_class // 2, seed=args.seed + 1)
        # A standard pipeline, except that Normalize moved out of the folder's transform (it comes after the camera).
        train_set = ImageFolder(str(train_root), transform=v2.Compose([v2.ToImage(), v2.RandomHorizontalFlip()]))
        val_set = ImageFolder(str(val_root), transform=v2.ToImage())
        val_clean = DegradedDataset(val_set, profile, Bernoulli(0.0), seed=1, transform=normalize)
        val_camera = DegradedDataset(val_set, profile, Bernoulli(1.0), seed=1, transform=normalize)

        if args.batch_path:
            train_data = IndexedDataset(train_set)  # camdegrade: the loader also returns each item's index
            batch_degrade = BatchDegrade(profile, p=0.5, seed=args.seed)  # camdegrade: degrade on the device
        else:
            train_data = DegradedDataset(  # camdegrade: clean + degraded, the paper's union
                train_set, CameraDegrade(profile), policy=Union(), seed=args.seed, transform=normalize
            )
        loader = DataLoader(train_data, batch_size=16, shuffle=True, num_workers=args.workers)
        model = small_cnn(len(CLASSES)).to(device)
        optimizer = torch.optim.Adam(model.parameters(), lr=0.003)
        loss_fn = nn.CrossEntropyLoss()

        for epoch in range(args.epochs):
            model.train()
            if args.batch_path:
                batch_degrade.set_epoch(epoch)  # camdegrade
            else:
                train_data.set_epoch(epoch)  # camdegrade
            total_loss = 0.0
            for batch in loader:
                if args.batch_path:
                    indices, (images, labels) = batch
                    images = normalize(batch_degrade(images.to(device), indices))  # camdegrade
                else:
                    images, labels = batch
                images, labels = images.to(device), labels.to(device)
                optimizer.zero_grad()
                loss = loss_fn(model(images), labels)
                loss.backward()
                optimizer.step()
                total_loss += loss.item() * labels.numel()
            print(f"epoch {epoch}: train loss {total_loss / len(train_data):.3f}")

        metrics = {
            "accuracy_clean": evaluate(model, DataLoader(val_clean, batch_size=32), device),
            "accuracy_camera": evaluate(model, DataLoader(val_camera, batch_size=32), device),
        }
    print(f"validation accuracy: clean {metrics['accuracy_clean']:.3f}, camera {metrics['accuracy_camera']:.3f}")
    return metrics


if __name__ == "__main__":
    main()
