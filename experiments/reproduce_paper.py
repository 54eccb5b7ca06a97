"""Reproduce Hegde et al.'s Tables I–II offline on CPU, with a virtual camera standing in for the real one.

The task: 5-way classification of the *stripe period* of a textured shape composited on a natural-image
background (scikit-image's sample photographs; generated backgrounds when scikit-image is missing). Fine stripes
are exactly what the cheap camera destroys (lens blur, half-resolution sensor, noise, JPEG 45), so a classifier
trained on clean images breaks on captures. The "real camera" is the ``lowcost-robot`` virtual camera; the
"in the wild" test set is re-rendered with other lighting and distance and captured by ``lowcost-robot-wild``
(per-shot exposure, white balance, gain and JPEG quality).

Rows (the paper's four, then ablations), each trained with 3+ seeds and tested on clean, captured and wild images:

- ``source``: trained on clean images only;
- ``zero-shot``: clean + images degraded by a profile fitted on pairs whose content holds *no task class*
  (background-only crops and shapes filled with non-periodic noise textures, captured by the camera);
- ``unsupervised``: the same, with the profile fitted on captured task images (labels unused);
- ``oracle``: trained on the camera's own captures of the training images;
- ablations of the zero-shot profile: network only (no fitted effect stages) and the mixing policy
  (``Union`` — the paper's, ``Bernoulli(0.5)``, ``PairedViews`` with a consistency loss).

Run from the repo root (the full run; ``--quick`` is the smoke test's one-seed version)::

    .venv/bin/python experiments/reproduce_paper.py --out out/paper
    .venv/bin/python experiments/reproduce_paper.py --quick
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn
from torch.utils.data import DataLoader, TensorDataset

from camdegrade import CameraProfile, DegradedDataset, VirtualCamera, fit_profile, simulate_pairs
from camdegrade.data import Bernoulli, MixPolicy, PairedViews, Union
from camdegrade.fitting import FitConfig
from camdegrade.io import write_image

#: Stripe period (pixels at the 64² rendering) of each class; neighbours differ by a factor √2.
PERIODS = (3.0, 4.25, 6.0, 8.5, 12.0)
MEAN, STD = 0.45, 0.25
#: The paper's gap closed (zero-shot, real captures): Table I (2-way) and Table II (5-way).
PAPER_GAP_CLOSED = {"2-way": 0.91, "5-way": 0.44}
ROWS = ("source", "zero-shot", "unsupervised", "oracle")
ABLATIONS = ("zero-shot network only", "zero-shot Bernoulli(0.5)", "zero-shot Pair + consistency")
COLUMNS = ("clean", "captured", "wild")


@dataclass(frozen=True)
class Settings:
    """Sizes of one run; ``--quick`` shrinks them."""

    size: int = 64
    train_per_class: int = 128
    test_per_class: int = 100
    fit_pairs: int = 128
    fit_epochs: int = 20
    fit_crop: int = 48
    fit_crops_per_pair: int = 2
    epochs: int = 10
    batch_size: int = 64
    lr: float = 0.003
    ablations: bool = True


QUICK = Settings(train_per_class=96, test_per_class=60, fit_pairs=96, fit_epochs=16, epochs=10, ablations=False)


# ----------------------------------------------------------------------------------------------- scene synthesis


@functools.cache
def _photographs() -> tuple[list[Tensor], list[Tensor]]:
    """(train, test) background sources: scikit-image's colour photographs as float (3, H, W), or generated
    backgrounds when scikit-image is not installed. Train and test sources never overlap."""
    try:
        from skimage import data as skdata
    except ImportError:
        return [], []

    def load(name: str) -> Tensor:
        array = skdata.stereo_motorcycle()[0] if name == "motorcycle" else getattr(skdata, name)()
        return torch.from_numpy(array[..., :3].copy()).permute(2, 0, 1).float() / 255.0

    train = [load(n) for n in ("astronaut", "coffee", "rocket", "immunohistochemistry", "hubble_deep_field")]
    test = [load(n) for n in ("chelsea", "motorcycle", "retina")]
    return train, test


def _generated_background(size: int, generator: torch.Generator) -> Tensor:
    """A smooth random colour field with a few soft blobs (the fallback when scikit-image is missing)."""
    coarse = torch.rand(1, 3, 5, 5, generator=generator)
    image = F.interpolate(coarse, size=(size, size), mode="bicubic", align_corners=False)[0]
    yy, xx = torch.meshgrid(torch.arange(size).float(), torch.arange(size).float(), indexing="ij")
    for _ in range(4):
        cy, cx, radius = (torch.rand(3, generator=generator) * torch.tensor([size, size, size / 4])).tolist()
        colour = torch.rand(3, 1, 1, generator=generator)
        weight = torch.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * (radius + 2) ** 2))
        image = image * (1 - weight) + colour * weight
    return image.clamp(0, 1)


def background(split: str, size: int, generator: torch.Generator) -> Tensor:
    """A random ``size``² crop (covering 64–256 px of the source, flipped at random) of a photograph of ``split``."""
    train, test = _photographs()
    sources = train if split == "train" else test
    if not sources:
        return _generated_background(size, generator)
    image = sources[int(torch.randint(len(sources), (1,), generator=generator))]
    height, width = image.shape[-2:]
    side = int(torch.randint(size, min(4 * size, height, width) + 1, (1,), generator=generator))
    top = int(torch.randint(height - side + 1, (1,), generator=generator))
    left = int(torch.randint(width - side + 1, (1,), generator=generator))
    crop = image[None, :, top : top + side, left : left + side]
    crop = F.interpolate(crop, size=(size, size), mode="bilinear", antialias=True, align_corners=False)[0]
    return crop.flip(-1) if float(torch.rand((), generator=generator)) < 0.5 else crop


def _shape_mask(size: int, scale: float, generator: torch.Generator) -> Tensor:
    """A soft-edged ellipse, rotated rectangle or diamond covering a good part of the image, as (1, H, W)."""
    u = lambda low, high: low + (high - low) * float(torch.rand((), generator=generator))  # noqa: E731
    kind = int(torch.randint(3, (1,), generator=generator))
    cy, cx = u(0.35, 0.65) * size, u(0.35, 0.65) * size
    a, b = u(0.22, 0.34) * size * scale, u(0.18, 0.3) * size * scale
    angle = u(0, math.pi)
    yy, xx = torch.meshgrid(torch.arange(size).float() + 0.5, torch.arange(size).float() + 0.5, indexing="ij")
    du, dv = xx - cx, yy - cy
    p = du * math.cos(angle) + dv * math.sin(angle)
    q = -du * math.sin(angle) + dv * math.cos(angle)
    if kind == 0:
        distance = (torch.sqrt((p / a) ** 2 + (q / b) ** 2) - 1) * min(a, b)
    elif kind == 1:
        distance = torch.maximum(p.abs() - a, q.abs() - b)
    else:
        distance = (p.abs() / a + q.abs() / b - 1) * min(a, b) / 1.4
    return torch.sigmoid(-distance * 2.0)[None]


def _grating(size: int, period: float, generator: torch.Generator) -> Tensor:
    """Sinusoidal stripes of ``period`` pixels at a random angle and phase, in [-1, 1], as (1, H, W)."""
    angle = float(torch.rand((), generator=generator)) * math.pi
    phase = float(torch.rand((), generator=generator)) * 2 * math.pi
    yy, xx = torch.meshgrid(torch.arange(size).float(), torch.arange(size).float(), indexing="ij")
    return torch.cos(2 * math.pi * (xx * math.cos(angle) + yy * math.sin(angle)) / period + phase)[None]


def _noise_texture(size: int, generator: torch.Generator) -> Tensor:
    """Non-periodic texture in [-1, 1]: white noise smoothed at a random scale (a non-class content)."""
    cells = int(torch.randint(size // 6, size + 1, (1,), generator=generator))
    noise = torch.rand(1, 1, cells, cells, generator=generator) * 2 - 1
    return F.interpolate(noise, size=(size, size), mode="bilinear", align_corners=False)[0].clamp(-1, 1)


def render(
    label: int | None, split: str, size: int, generator: torch.Generator, *, scale: float = 1.0, light: float = 1.0
) -> Tensor:
    """One scene as uint8 (3, size, size): a background with a shape whose fill has stripes of class ``label``'s
    period (``None``: a non-periodic noise fill; ``-1``: no shape). ``scale`` stands for the distance (shape size
    and stripe period scale together); ``light`` multiplies the scene's radiance."""
    image = background(split, size, generator)
    if label is not None and label >= 0:
        texture = _grating(size, PERIODS[label] * scale, generator)
    elif label is None:
        texture = _noise_texture(size, generator)
    if label is None or label >= 0:
        colour = 0.2 + 0.6 * torch.rand(3, 1, 1, generator=generator)
        contrast = 0.3 + 0.3 * float(torch.rand((), generator=generator))
        fill = (colour * (1 + contrast * texture)).clamp(0, 1)
        mask = _shape_mask(size, scale, generator)
        image = image * (1 - mask) + fill * mask
    return (image * light).mul(255).round().clamp(0, 255).to(torch.uint8)


def render_set(labels: Sequence[int | None], split: str, size: int, seed: int, *, wild: bool = False) -> Tensor:
    """Scenes for ``labels`` as uint8 (N, 3, size, size), seeded; ``wild`` varies distance (±12 %) and light
    (×0.6–1.3) per scene."""
    generator = torch.Generator().manual_seed(seed)
    images = []
    for label in labels:
        scale, light = 1.0, 1.0
        if wild:
            scale = 0.88 + 0.24 * float(torch.rand((), generator=generator))
            light = 0.6 + 0.7 * float(torch.rand((), generator=generator))
        images.append(render(label, split, size, generator, scale=scale, light=light))
    return torch.stack(images)


def capture(camera: VirtualCamera, images: Tensor, seed: int, batch: int = 64) -> Tensor:
    """The virtual camera's captures of uint8 ``images``, seeded."""
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        return torch.cat([camera(images[i : i + batch], generator=generator) for i in range(0, len(images), batch)])


# -------------------------------------------------------------------------------------------------- profile fitting


def fit_camera_profile(
    camera: VirtualCamera, clean: Tensor, settings: Settings, seed: int, work: Path, name: str
) -> CameraProfile:
    """Write ``clean`` images, capture them with the virtual camera (:func:`simulate_pairs`), and fit a profile on
    the pairs with :func:`fit_profile` (the paper's recipe, fewer epochs and small crops; noise and vignetting
    stages fitted after the network by default)."""
    sources = work / f"{name}-sources"
    for index, image in enumerate(clean):
        write_image(image, sources / f"{index:04d}.png")
    simulate_pairs(camera, sources, work / f"{name}-pairs", seed=seed)
    recipe = FitConfig.recipe("paper").replace(
        epochs=settings.fit_epochs,
        crop=settings.fit_crop,
        crops_per_pair=settings.fit_crops_per_pair,
        lr_halving_epochs=max(1, settings.fit_epochs // 3),
        seed=seed,
    )
    return fit_profile(work / f"{name}-pairs", recipe, name=name)


def network_only(profile: CameraProfile) -> CameraProfile:
    """The same profile without its fitted effect stages (the paper's model: the network alone)."""
    return CameraProfile(profile.network, name=f"{profile.name} (network only)")


# ------------------------------------------------------------------------------------------- classifier training


def classifier(classes: int) -> nn.Module:
    """A small CNN (64k parameters) for 64² inputs; its stride-2 4×4 stem still sees 3-pixel stripes."""

    def block(cin: int, cout: int, kernel: int, stride: int) -> list[nn.Module]:
        conv = nn.Conv2d(cin, cout, kernel, stride=stride, padding=1, bias=False)
        return [conv, nn.BatchNorm2d(cout), nn.ReLU()]

    return nn.Sequential(
        *block(3, 24, 4, 2),
        *block(24, 32, 3, 2),
        *block(32, 64, 3, 2),
        *block(64, 64, 3, 1),
        nn.AdaptiveAvgPool2d(1),
        nn.Flatten(),
        nn.Linear(64, classes),
    )


def _normalize(images: Tensor) -> Tensor:
    return (images.float() / 255.0 - MEAN) / STD


@dataclass(frozen=True)
class Recipe:
    """How one classifier is trained: on ``images`` alone, or mixed with a profile's degradations by ``policy``."""

    profile: CameraProfile | None = None
    policy: MixPolicy | None = None
    consistency: float = 0.0


def train_classifier(
    images: Tensor, labels: Tensor, recipe: Recipe, settings: Settings, seed: int, classes: int
) -> nn.Module:
    """Train :func:`classifier` with Adam; degraded views come from :class:`DegradedDataset` (per item, epoch and
    seed, independent of loading order). ``PairedViews`` trains on both views with a KL consistency term."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        model = classifier(classes)
    data: Any = TensorDataset(images, labels)
    if recipe.profile is not None:
        data = DegradedDataset(data, recipe.profile, policy=recipe.policy or Union(), seed=seed)
    loader = DataLoader(
        data, batch_size=settings.batch_size, shuffle=True, generator=torch.Generator().manual_seed(seed)
    )
    optimizer = torch.optim.Adam(model.parameters(), lr=settings.lr)
    steps = settings.epochs * len(loader)
    scheduler = torch.optim.lr_scheduler.OneCycleLR(optimizer, max_lr=settings.lr, total_steps=steps)
    for epoch in range(settings.epochs):
        if isinstance(data, DegradedDataset):
            data.set_epoch(epoch)
        model.train()
        for batch in loader:
            if isinstance(recipe.policy, PairedViews):
                (clean, target), (degraded, _) = batch
                logits = model(_normalize(torch.cat([clean, degraded])))
                loss = F.cross_entropy(logits, torch.cat([target, target]))
                if recipe.consistency:
                    clean_logp, degraded_logp = logits.log_softmax(1).chunk(2)
                    loss = loss + recipe.consistency * F.kl_div(
                        degraded_logp, clean_logp.detach(), log_target=True, reduction="batchmean"
                    )
            else:
                batch_images, target = batch
                loss = F.cross_entropy(model(_normalize(batch_images)), target)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            scheduler.step()
    return model.eval()


def accuracy(model: nn.Module, images: Tensor, labels: Tensor, batch: int = 250) -> float:
    with torch.no_grad():
        chunks = [model(_normalize(images[i : i + batch])).argmax(1) for i in range(0, len(images), batch)]
    predictions = torch.cat(chunks)
    return float((predictions == labels).float().mean())


# ---------------------------------------------------------------------------------------------------- experiment


def run_seed(seed: int, settings: Settings, work: Path, log: Callable[[str], None]) -> dict[str, dict[str, float]]:
    """All rows for one seed: render data, capture it, fit the two profiles, train and test every classifier."""
    classes = len(PERIODS)
    camera = VirtualCamera.from_preset("lowcost-robot")
    wild_camera = VirtualCamera.from_preset("lowcost-robot-wild")
    base = 1000 * seed
    train_labels = torch.arange(classes).repeat_interleave(settings.train_per_class)
    test_labels = torch.arange(classes).repeat_interleave(settings.test_per_class)
    train = render_set(train_labels.tolist(), "train", settings.size, base + 1)
    test_clean = render_set(test_labels.tolist(), "test", settings.size, base + 2)
    test = {
        "clean": test_clean,
        "captured": capture(camera, test_clean, base + 3),
        "wild": capture(
            wild_camera, render_set(test_labels.tolist(), "test", settings.size, base + 4, wild=True), seed=base + 5
        ),
    }
    train_captured = capture(camera, train, base + 6)

    # Zero-shot pairs: half background only, half shapes with non-periodic fills; no task class anywhere.
    half = settings.fit_pairs // 2
    zero_shot_content = render_set([-1] * half + [None] * (settings.fit_pairs - half), "train", settings.size, base + 7)
    # Unsupervised pairs: new task-class scenes, their labels thrown away.
    unlabeled = render_set((torch.arange(settings.fit_pairs) % classes).tolist(), "train", settings.size, base + 8)
    started = time.perf_counter()
    zero_shot = fit_camera_profile(camera, zero_shot_content, settings, base + 9, work / f"seed{seed}", "zero-shot")
    unsupervised = fit_camera_profile(camera, unlabeled, settings, base + 10, work / f"seed{seed}", "unsupervised")
    log(
        f"seed {seed}: profiles fitted in {time.perf_counter() - started:.0f} s; validation PSNR (network) "
        f"zero-shot {zero_shot.quality.get('network_psnr_db')} dB, unsupervised "
        f"{unsupervised.quality.get('network_psnr_db')} dB (identity {zero_shot.quality.get('identity_psnr_db')} dB)"
    )

    recipes: dict[str, tuple[Tensor, Recipe]] = {
        "source": (train, Recipe()),
        "zero-shot": (train, Recipe(zero_shot, Union())),
        "unsupervised": (train, Recipe(unsupervised, Union())),
        "oracle": (train_captured, Recipe()),
    }
    if settings.ablations:
        recipes["zero-shot network only"] = (train, Recipe(network_only(zero_shot), Union()))
        recipes["zero-shot Bernoulli(0.5)"] = (train, Recipe(zero_shot, Bernoulli(0.5)))
        recipes["zero-shot Pair + consistency"] = (train, Recipe(zero_shot, PairedViews(), consistency=1.0))
    results = {}
    for row, (images, recipe) in recipes.items():
        started = time.perf_counter()
        model = train_classifier(images, train_labels, recipe, settings, base + 11, classes)
        results[row] = {column: accuracy(model, test[column], test_labels) for column in COLUMNS}
        scores = "  ".join(f"{column} {100 * value:5.1f}" for column, value in results[row].items())
        log(f"seed {seed}: {row:<30} {scores}  ({time.perf_counter() - started:.0f} s)")
    return results


def summarize(per_seed: list[dict[str, dict[str, float]]]) -> dict[str, Any]:
    """Mean and standard deviation (in %) of every row and column, and the share of the source → oracle gap that
    each row closes (from the mean accuracies)."""
    rows = list(per_seed[0])
    table: dict[str, Any] = {}
    for row in rows:
        table[row] = {}
        for column in COLUMNS:
            values = [100 * seed[row][column] for seed in per_seed]
            std = statistics.stdev(values) if len(values) > 1 else 0.0
            table[row][column] = {"mean": round(statistics.fmean(values), 2), "std": round(std, 2)}
    gap: dict[str, dict[str, float | None]] = {}
    for row in rows:
        gap[row] = {}
        for column in COLUMNS:
            source, oracle = table["source"][column]["mean"], table["oracle"][column]["mean"]
            closed = (table[row][column]["mean"] - source) / (oracle - source) if oracle != source else None
            gap[row][column] = None if closed is None else round(closed, 3)
    return {"table": table, "gap_closed": gap}


def format_table(summary: dict[str, Any], seeds: int) -> str:
    """A Markdown table: accuracy mean ± std over the seeds, and the share of the gap closed on captures."""
    lines = [
        f"| row ({seeds} seed{'s' if seeds > 1 else ''}) | clean test | captured test | in the wild "
        "| gap closed (captured) |",
        "|---|---|---|---|---|",
    ]
    for row, columns in summary["table"].items():
        cells = [f"{columns[c]['mean']:.1f} ± {columns[c]['std']:.1f}" for c in COLUMNS]
        closed = summary["gap_closed"][row]["captured"]
        lines.append(f"| {row} | {' | '.join(cells)} | {'' if closed is None else f'{100 * closed:.0f} %'} |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one seed, smaller data, no ablations (≤ 3 min)")
    parser.add_argument("--seeds", type=int, nargs="+", help="seeds (default: 0 1 2; --quick: 0)")
    parser.add_argument("--no-ablations", action="store_true")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--out", type=Path, default=Path("out/paper"), help="folder for results.json")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    settings = QUICK if args.quick else Settings()
    if args.no_ablations:
        settings = replace(settings, ablations=False)
    seeds = args.seeds or ([0] if args.quick else [0, 1, 2])
    log = functools.partial(print, flush=True, file=sys.stderr)
    started = time.perf_counter()
    per_seed = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            per_seed.append(run_seed(seed, settings, Path(tmp), log))
    summary = summarize(per_seed)
    seconds = time.perf_counter() - started
    results = {
        "settings": asdict(settings),
        "seeds": seeds,
        "per_seed": per_seed,
        **summary,
        "paper_gap_closed_zero_shot": PAPER_GAP_CLOSED,
        "backgrounds": "scikit-image photographs" if _photographs()[0] else "generated",
        "seconds": round(seconds, 1),
        "machine": f"{platform.machine()}, {args.threads} torch thread(s), torch {torch.__version__}",
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps(results, indent=2) + "\n")
    print(format_table(summary, len(seeds)))
    print(f"\n{seconds / 60:.1f} min on {results['machine']}; results in {args.out / 'results.json'}")
    return results


if __name__ == "__main__":
    main()
