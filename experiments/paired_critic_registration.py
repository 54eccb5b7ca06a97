"""What the paired critic keys on when it tells the City100 built-in from the iPhone X: the capture's registration
to its clean source (issue 23, item 0).

The paired critic of :mod:`camdegrade.measures.critic` sees the clean source beside the image (and their
difference); no change to the image's look has moved it (docs/results.md). Its suspect here is registration: a
capture is aligned to its clean image only up to sub-pixel, locally varying errors, where the simulation is exact
by construction. This script measures those errors and re-runs the critic on rows that change only the geometry.

- **Misregistration.** Per 64×64 tile of the luma (Gaussian σ 1), one least-squares (Lucas–Kanade) step for the
  shift that takes the simulation onto the capture; tiles without texture in both directions are left out. Printed:
  the tiles, the mean shift and the RMS of the tiles' shifts about their frame's mean (the local part).
- **Rows**, each on the 16 held-out scenes (056–070, 098; never used in any fit), whole frames, 8-bit, trained on
  the even scenes and scored on the odd ones and back, ``--seeds`` critic seeds: the profile sampled as training
  sees it; the capture shifted by 0.5 px, and warped by a smooth random field (how sensitive is the critic to
  geometry alone?); the profile warped by the capture's measured misregistration (the tiles' shifts, interpolated);
  the profile warped by smooth random fields of 0.3, 0.5 and 1 px RMS. Warps resample bicubically (a bilinear one
  would blur). Run from the repo root::

    OMP_NUM_THREADS=2 .venv/bin/python experiments/paired_critic_registration.py [--profile city100-iphonex]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import torch
import torch.nn.functional as F
from critic_ablation_fit import DEFAULT_DATA, HELD_OUT, MODES, ROOT, city100_pairs, critic_scores, eight_bit
from torch import Tensor

from camdegrade import CameraDegrade, load_profile
from camdegrade.functional import blur_image
from camdegrade.functional.analysis.images import luma

#: Tile side of the misregistration estimate (pixels) and the smallest eigenvalue of a tile's gradient matrix
#: (sum of squared luma gradients, unit range) below which it has too little texture to say where it lies.
TILE = 64
MIN_TEXTURE = 1e-3


def warped(image: Tensor, dx: Tensor | float, dy: Tensor | float) -> Tensor:
    """``image`` ``(3, H, W)`` sampled at ``(x + dx, y + dy)`` (pixels; fields ``(H, W)`` or numbers), bicubic,
    the border repeated."""
    _, height, width = image.shape
    ys, xs = torch.meshgrid(torch.arange(height), torch.arange(width), indexing="ij")
    grid_x = (xs + dx + 0.5) / width * 2 - 1
    grid_y = (ys + dy + 0.5) / height * 2 - 1
    grid = torch.stack([grid_x, grid_y], dim=-1)[None].float()
    return F.grid_sample(image[None], grid, mode="bicubic", padding_mode="border", align_corners=False)[0]


def random_field(height: int, width: int, rms: float, scale: int, seed: int) -> tuple[Tensor, Tensor]:
    """A smooth random displacement ``(dx, dy)`` of ``rms`` pixels: normal samples every ``scale`` pixels,
    bicubically interpolated."""
    generator = torch.Generator().manual_seed(seed)
    knots = torch.randn(2, height // scale + 2, width // scale + 2, generator=generator)
    field = F.interpolate(knots[None], size=(height, width), mode="bicubic", align_corners=False)[0]
    field = field / field.pow(2).mean().sqrt() * rms
    return field[0], field[1]


def tile_shifts(real: Tensor, sim: Tensor) -> Tensor:
    """``(rows, cols, 2)`` shifts ``(dx, dy)`` with ``real(x) ≈ sim(x + shift)`` per :data:`TILE` tile (NaN where a
    tile has too little texture), clamped to ±3 px (one linearised step)."""
    target, source = luma(blur_image(real, 1.0)), luma(blur_image(sim, 1.0))
    grad_y, grad_x = torch.gradient(source)
    difference = target - source
    rows, cols = target.shape[0] // TILE, target.shape[1] // TILE
    shifts = torch.full((rows, cols, 2), float("nan"))
    for row in range(rows):
        for col in range(cols):
            window = (slice(row * TILE, (row + 1) * TILE), slice(col * TILE, (col + 1) * TILE))
            basis = torch.stack([grad_x[window].flatten(), grad_y[window].flatten()], dim=1).double()
            normal = basis.T @ basis
            if torch.linalg.eigvalsh(normal)[0] < MIN_TEXTURE:
                continue
            shift = torch.linalg.solve(normal, basis.T @ difference[window].flatten().double())
            shifts[row, col] = shift.clamp(-3.0, 3.0).float()
    return shifts


def shift_field(shifts: Tensor, height: int, width: int) -> tuple[Tensor, Tensor]:
    """The tiles' shifts as a full-resolution field (tiles without an estimate take the frame's mean), bilinear."""
    found = torch.isfinite(shifts[..., 0])
    mean = shifts[found].mean(dim=0) if bool(found.any()) else torch.zeros(2)
    filled = torch.where(found[..., None], shifts, mean).permute(2, 0, 1)
    field = F.interpolate(filled[None], size=(height, width), mode="bilinear", align_corners=False)[0]
    return field[0], field[1]


def misregistration(reals: list[Tensor], sims: list[Tensor]) -> tuple[list[Tensor], dict[str, float]]:
    shifts = [tile_shifts(real, sim) for real, sim in zip(reals, sims, strict=True)]
    local = []
    for frame in shifts:
        found = frame[torch.isfinite(frame[..., 0])]
        local.append(found - found.mean(dim=0))
    stacked, deviations = torch.cat([s[torch.isfinite(s[..., 0])] for s in shifts]), torch.cat(local)
    summary = {
        "tiles": len(stacked),
        "mean_dx": float(stacked[:, 0].mean()),
        "mean_dy": float(stacked[:, 1].mean()),
        "local_rms_px": float(deviations.pow(2).sum(dim=1).mean().sqrt()),
    }
    return shifts, summary


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--profile", default="city100-iphonex", help="built-in name or .safetensors path")
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--seeds", type=int, default=2, help="critic seeds per row and mode (default 2)")
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "results" / "paired_critic_registration.json")
    args = parser.parse_args(argv)
    if not (args.data / "pairs.csv").is_file():
        parser.error(f"no pairs.csv in {args.data}; pass --data with the real-pairs folder")
    started = time.perf_counter()
    held = city100_pairs(args.data, HELD_OUT)
    cleans, reals = [clean for clean, _ in held], [real for _, real in held]
    profile = load_profile(args.profile)
    sims = [eight_bit(CameraDegrade(profile, seed=index)(clean).clamp(0, 1)) for index, clean in enumerate(cleans)]
    shifts, summary = misregistration(reals, sims)
    print(
        f"misregistration, capture against simulation: {summary['tiles']} tiles of {TILE}², mean shift "
        f"dx {summary['mean_dx']:+.2f} dy {summary['mean_dy']:+.2f} px, local RMS {summary['local_rms_px']:.2f} px"
    )

    def random_warp(image: Tensor, rms: float, scale: int, index: int) -> Tensor:
        return eight_bit(warped(image, *random_field(*image.shape[1:], rms, scale, index)))

    rows = {
        "profile": lambda i: sims[i],
        "capture shifted 0.5 px": lambda i: eight_bit(warped(reals[i], 0.5, 0.0)),
        "capture warped, random 0.5 px RMS (32 px)": lambda i: random_warp(reals[i], 0.5, 32, i),
        "profile warped by the capture's measured misregistration": lambda i: eight_bit(
            warped(sims[i], *shift_field(shifts[i], *sims[i].shape[1:]))
        ),
        "profile warped, random 0.3 px RMS (64 px)": lambda i: random_warp(sims[i], 0.3, 64, i),
        "profile warped, random 0.5 px RMS (32 px)": lambda i: random_warp(sims[i], 0.5, 32, i),
        "profile warped, random 1 px RMS (64 px)": lambda i: random_warp(sims[i], 1.0, 64, i),
    }
    print("| row | image-only | paired |")
    print("|---|---|---|")
    record = {"misregistration": summary, "rows": {}}
    for name, row in rows.items():
        with torch.no_grad():
            images = [row(index) for index in range(len(held))]
        scores = critic_scores(cleans, reals, images, args.seeds)
        cells = [f"{statistics.mean(scores[mode]):.3f} ± {statistics.stdev(scores[mode]):.3f}" for mode in MODES]
        print(f"| {name} | {' | '.join(cells)} |", flush=True)
        record["rows"][name] = scores
    seconds = time.perf_counter() - started
    print(f"{len(rows) * len(MODES) * 2 * args.seeds} critics; {seconds:.0f} s in all")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(record | {"seconds": round(seconds, 1)}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
