"""Issue 43's PolyU unpaired case: what tells the captures from the profile's simulation, on absolutely flat pixels.

The case of ``experiments/unpaired_polyu_noise.py`` (10 PolyU crops of 128², JPEG q85, beside 89 other scenes'
mean frames) is fitted, then each variant of the profile is simulated from the captures' OWN mean frames (the same
scenes: content cannot differ) and its noise (the simulation less the variant's noiseless output; the captures less
their mean frames, each less its mean on its flat pixels: shot-to-shot exposure) is read where the mean frame is
flat (:func:`~camdegrade.functional.analysis.images.flat_mask`):

- std of luma and chroma (JPEG's YCbCr), the channels' correlation, the luma's and the chroma's correlation at lags
  1, 2 and 4 (both pixels flat), the share of the chroma's power below 0.125 cycles/px (flat 16×16 tiles);
- the codec's marks: the luma differences across the 8×8 grid's block edges over those inside, and the share of
  the luma DCT coefficients at ``u + v ≥ 6`` of the flat 8×8 blocks under 0.75 (a JPEG's zeros).

With ``--seeds N``: the image-only critic of the fit's own check (``judges.self_check_critic``'s images) with N
seeds (2N critics), against the other scenes and the true clean images. With ``--png``: capture | the chain without
its codec | the chain, per scene: the most textured 48² at 2× (nearest), the flattest 64² at 1:1, and that flat
patch's deviation from the mean frame (less its mean) ×4 at 2×. Run from the repo root::

    OMP_NUM_THREADS=1 .venv/bin/python experiments/unpaired_polyu_codec.py [REAL_PAIRS_DIR] [--seeds 5] [--png OUT]
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parent))

from unpaired_polyu_noise import default_real_pairs_dir, write_sets

from camdegrade import CameraProfile
from camdegrade._support.pixels import as_unit
from camdegrade.effects import JPEG
from camdegrade.effects.base import evenly_spaced
from camdegrade.fitting.unpaired import fit_unpaired
from camdegrade.fitting.unpaired.images import load_images
from camdegrade.fitting.unpaired.judges import CRITIC_IMAGES, common_crops
from camdegrade.functional.analysis.images import flat_mask
from camdegrade.io import read_image
from camdegrade.measures.critic import repeated_critic_test

YCC = torch.tensor([[0.299, 0.587, 0.114], [-0.168736, -0.331264, 0.5], [0.5, -0.418688, -0.081312]])


def _dct() -> torch.Tensor:
    k = torch.arange(8.0)
    basis = torch.cos(math.pi * (2 * k[None] + 1) * k[:, None] / 16) * math.sqrt(2 / 8)
    basis[0] /= math.sqrt(2)
    return basis


def _lag(fields: list[torch.Tensor], masks: list[torch.Tensor], lag: int) -> float:
    """Correlation of a ``(H, W)`` field with itself ``lag`` pixels on (across and down), both pixels flat."""
    first, second = [], []
    for field, mask in zip(fields, masks, strict=True):
        for axis in (0, 1):
            size = field.shape[axis] - lag
            both = mask.narrow(axis, 0, size) & mask.narrow(axis, lag, size)
            first.append(field.narrow(axis, 0, size)[both])
            second.append(field.narrow(axis, lag, size)[both])
    return float(torch.corrcoef(torch.stack([torch.cat(first), torch.cat(second)]))[0, 1])


def _block_edges(lumas: list[torch.Tensor], masks: list[torch.Tensor]) -> float:
    """Mean squared luma difference across the 8×8 grid's block edges over that inside the blocks."""
    energy, count = torch.zeros(8), torch.zeros(8)
    for luma, mask in zip(lumas, masks, strict=True):
        for axis in (0, 1):
            size = luma.shape[axis] - 1
            diff = (luma.narrow(axis, 1, size) - luma.narrow(axis, 0, size)) ** 2
            both = mask.narrow(axis, 1, size) & mask.narrow(axis, 0, size)
            phase = torch.arange(size) % 8
            phase = (phase.view(-1, 1) if axis == 0 else phase.view(1, -1)).expand_as(diff)
            energy.index_add_(0, phase[both], diff[both])
            count.index_add_(0, phase[both], torch.ones(int(both.sum())))
    mean = energy / count
    return float(mean[7] / mean[:7].mean())


def _dct_zeros(images: list[torch.Tensor], masks: list[torch.Tensor]) -> tuple[float, int]:
    """Share of the luma DCT coefficients at ``u + v ≥ 6`` under 0.75 on the flat 8×8 blocks, and the blocks."""
    basis, high = _dct(), (torch.arange(8)[:, None] + torch.arange(8)[None]) >= 6
    values = []
    for image, mask in zip(images, masks, strict=True):
        luma = torch.einsum("c,chw->hw", YCC[0], image * 255)
        blocks = luma.unfold(0, 8, 8).unfold(1, 8, 8).reshape(-1, 8, 8)
        flat = mask.unfold(0, 8, 8).unfold(1, 8, 8).reshape(-1, 64).all(1)
        values.append((basis @ blocks[flat] @ basis.T)[:, high].flatten())
    values = torch.cat(values)
    return float((values.abs() < 0.75).float().mean()), int(values.numel() // int(high.sum()))


def _low_chroma(fields: list[torch.Tensor], masks: list[torch.Tensor]) -> tuple[float, int]:
    """Share of a field's power below 0.125 cycles/px on the flat 16×16 tiles (the grid's), and the tiles."""
    frequency = torch.fft.fftfreq(16)
    low = (frequency[:, None] ** 2 + frequency[None] ** 2).sqrt() < 0.125
    below = total = 0.0
    tiles = 0
    for field, mask in zip(fields, masks, strict=True):
        patches = field.unfold(0, 16, 16).unfold(1, 16, 16).reshape(-1, 16, 16)
        flat = mask.unfold(0, 16, 16).unfold(1, 16, 16).reshape(-1, 256).all(1)
        if not bool(flat.any()):
            continue
        centred = patches[flat] - patches[flat].mean((1, 2), keepdim=True)
        power = torch.fft.fft2(centred).abs() ** 2
        below, total, tiles = below + float(power[:, low].sum()), total + float(power.sum()), tiles + int(flat.sum())
    return below / total, tiles


def noise_row(images: list[torch.Tensor], references: list[torch.Tensor], masks: list[torch.Tensor]) -> dict:
    """The module's statistics of ``images`` less ``references`` (8-bit levels) on ``masks``."""
    noise = [(image - reference) * 255 for image, reference in zip(images, references, strict=True)]
    ycc = [torch.einsum("kc,chw->khw", YCC, field) for field in noise]
    flat = torch.cat([field[:, mask] for field, mask in zip(noise, masks, strict=True)], 1)
    pooled = YCC @ flat
    channels = torch.corrcoef(flat)
    zeros, blocks = _dct_zeros(images, masks)
    low_cb, tiles = _low_chroma([field[1] for field in ycc], masks)
    return {
        "pixels": flat.shape[1],
        "std Y Cb Cr": [round(float(v), 2) for v in pooled.std(1)],
        "corr RG RB GB": [round(float(channels[i, j]), 2) for i, j in ((0, 1), (0, 2), (1, 2))],
        "luma lag 1/2/4": [round(_lag([f[0] for f in ycc], masks, lag), 2) for lag in (1, 2, 4)],
        "Cb lag 1/2/4": [round(_lag([f[1] for f in ycc], masks, lag), 2) for lag in (1, 2, 4)],
        "Cr lag 1/2/4": [round(_lag([f[2] for f in ycc], masks, lag), 2) for lag in (1, 2, 4)],
        "Cb power below 0.125": round(low_cb, 2),
        "block edges / inside": round(_block_edges([f[0] for f in ycc], masks), 2),
        "high luma DCT zeros": round(zeros, 3),
        "flat blocks / tiles": [blocks, tiles],
    }


def variants(profile: CameraProfile) -> dict[str, CameraProfile]:
    effects = list(profile.effects)
    noise = [effect for effect in effects if effect.name == "noise"]
    codec = [effect for effect in effects if effect.name == "jpeg"] or [JPEG(85)]
    return {
        "the chain without its codec": CameraProfile(None, [e for e in effects if e.name != "jpeg"]),
        "noise stage only": CameraProfile(None, noise),
        "noise stage + codec": CameraProfile(None, noise + codec),
        f"the chain ({', '.join(profile.effect_names)})": profile,
    }


def statistics(profile: CameraProfile, captured: Path, means: list[Path]) -> dict[str, dict]:
    cleans = [as_unit(read_image(path)).float() for path in means]
    captures = [as_unit(read_image(captured / f"{path.stem}.jpg")).float() for path in means]
    masks = [flat_mask(clean) for clean in cleans]
    offset = [
        capture - (capture - clean)[:, mask].mean(1)[:, None, None] if bool(mask.any()) else capture
        for capture, clean, mask in zip(captures, cleans, masks, strict=True)
    ]
    rows = {"captures (less each one's flat offset)": noise_row(offset, cleans, masks)}
    for label, part in variants(profile).items():
        simulated = part.simulate(cleans, 0, stream="codec-look", eight_bit=True)
        noiseless = [part.without_randomness()(clean[None])[0] for clean in cleans]
        rows[label] = noise_row(simulated, noiseless, masks)
    return rows


def critic(profile: CameraProfile, captured: Path, clean: Path, seeds: int) -> tuple[float, float, int]:
    """The own check's image-only critic with ``seeds`` seeds: mean, spread over its critics, critics."""
    cleans, captures = common_crops(
        evenly_spaced(load_images(clean, "clean").images, CRITIC_IMAGES),
        evenly_spaced(load_images(captured, "captured").images, CRITIC_IMAGES),
    )
    simulated = profile.simulate(cleans, 0, stream="unpaired-critic", eight_bit=True)
    scenes = [f"{index:04d}" for index in range(len(cleans))]
    spread = repeated_critic_test((cleans, captures, simulated), scenes, seeds, image_only=True)
    return round(spread.accuracy, 3), round(spread.std, 3), len(spread.accuracies)


def _tile(image: torch.Tensor, zoom: int) -> np.ndarray:
    array = (image.clamp(0, 1).permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
    return np.kron(array, np.ones((zoom, zoom, 1), np.uint8))


def _corner(score: torch.Tensor, side: int) -> tuple[int, int]:
    pooled = torch.nn.functional.avg_pool2d(score[None, None].float(), side, 8)[0, 0]
    row, column = divmod(int(pooled.argmax()), pooled.shape[1])
    return row * 8, column * 8


def write_png(profile: CameraProfile, captured: Path, means: list[Path], png: Path) -> None:
    parts = [variants(profile)["the chain without its codec"], profile]
    rows = []
    for path in (means[1], means[3], means[7]):
        clean = as_unit(read_image(path)).float()
        images = [as_unit(read_image(captured / f"{path.stem}.jpg")).float()]
        images += [part.simulate([clean], 3, stream="codec-png", eight_bit=True)[0] for part in parts]
        detail = (clean[:, 1:, 1:] - clean[:, :-1, 1:]).abs().mean(0) + (
            clean[:, 1:, 1:] - clean[:, 1:, :-1]
        ).abs().mean(0)
        (tr, tc), (fr, fc) = _corner(detail, 48), _corner(flat_mask(clean), 64)
        tiles = [_tile(image[:, tr : tr + 48, tc : tc + 48], 2) for image in images]
        tiles += [
            np.pad(_tile(image[:, fr : fr + 64, fc : fc + 64], 1), ((16, 16), (16, 16), (0, 0)), constant_values=255)
            for image in images
        ]
        for image in images:
            deviation = (image - clean)[:, fr : fr + 48, fc : fc + 48]
            tiles.append(_tile(0.5 + 4 * (deviation - deviation.mean((1, 2), keepdim=True)), 2))
        gap = np.full((96, 6, 3), 255, np.uint8)
        rows.append(np.concatenate([part for tile in tiles for part in (tile, gap)], 1))
    band = np.full((6, rows[0].shape[1], 3), 255, np.uint8)
    Image.fromarray(np.concatenate([part for row in rows for part in (row, band)], 0)).save(png)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("root", nargs="?", type=Path, default=default_real_pairs_dir())
    parser.add_argument("--seeds", type=int, default=0, help="critic seeds (2 critics each); 0: no critic")
    parser.add_argument("--png", type=Path, default=None)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as scratch:
        captured, clean, means = write_sets(args.root, Path(scratch))
        profile = fit_unpaired(captured, clean, seed=0)
        print(
            "kept:",
            profile.effect_names,
            "own check critic:",
            profile.quality["unpaired_fidelity"]["critic_image_only"],
        )
        print("warnings:", profile.fitted.get("warnings", []))
        for label, row in statistics(profile, captured, means).items():
            print(f"{label}: {row}")
        if args.seeds:
            for label, part in {**variants(profile), "no stage": CameraProfile(None, [])}.items():
                for side, folder in (("other scenes", clean), ("true clean", Path(scratch) / "captured_mean")):
                    print(f"critic, {label}, {side}: {critic(part, captured, folder, args.seeds)}", flush=True)
        if args.png is not None:
            write_png(profile, captured, means, args.png)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
