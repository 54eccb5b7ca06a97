"""``make demo``: degrade a few sample images with a built-in profile; write a side-by-side grid and a summary.

Rows: one per sample image. Columns: clean | degraded by the profile | |difference| × 4. The last two rows are at
1:1 (no resizing): the flattest 256² window of a photo and a generated sky-like gradient, where excess noise or
banding would show at once.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from torchvision.transforms.v2 import functional as TF
from torchvision.utils import make_grid

from camdegrade import CameraDegrade, list_profiles, load_profile, profile_summary
from camdegrade.functional.analysis.images import flat_mask
from camdegrade.io import write_image
from camdegrade.measures.metrics import psnr

SIZE = 256


def sample_images() -> dict[str, torch.Tensor]:
    """Natural images shipped with scikit-image when it is installed, one generated test chart, and two flat
    images at 1:1 (a photo's flattest window and a generated gradient)."""
    photos = {}
    try:
        from skimage import data

        for name in ("astronaut", "chelsea", "coffee"):
            array = getattr(data, name)()
            photos[name] = torch.from_numpy(array).permute(2, 0, 1).contiguous()
    except ImportError:
        pass
    images = {
        name: TF.resize(TF.center_crop(img, min(img.shape[-2:])), [SIZE, SIZE], antialias=True)
        for name, img in photos.items()
    }
    images["chart"] = test_chart(SIZE)
    if "coffee" in photos:
        images["coffee 1:1 flat"] = flattest_window(photos["coffee"], SIZE)
    images["sky 1:1"] = sky(SIZE)
    return images


def flattest_window(image: torch.Tensor, size: int) -> torch.Tensor:
    """The ``size``² window (no resizing) with the most pixels that are flat in absolute terms."""
    flat = flat_mask(image.float() / 255).float()
    pooled = torch.nn.functional.avg_pool2d(flat[None, None], size, stride=8)[0, 0]
    top, left = divmod(int(pooled.argmax()), pooled.shape[1])
    return image[:, top * 8 : top * 8 + size, left * 8 : left * 8 + size].contiguous()


def sky(size: int) -> torch.Tensor:
    """A generated sky: a smooth blue gradient over a dark band, flat everywhere at the pixel scale."""
    y = torch.linspace(0, 1, size)[:, None].expand(size, size)
    sky_rgb = torch.stack([0.25 + 0.3 * y, 0.45 + 0.3 * y, 0.85 - 0.1 * y])
    sky_rgb[:, 3 * size // 4 :] = torch.tensor([0.08, 0.07, 0.06])[:, None, None]
    return (sky_rgb * 255).round().to(torch.uint8)


def test_chart(size: int) -> torch.Tensor:
    """A generated chart: colour ramps, a zone plate (fine detail) and a gray step wedge."""
    y, x = torch.meshgrid(torch.linspace(0, 1, size), torch.linspace(0, 1, size), indexing="ij")
    radius2 = (x - 0.5) ** 2 + (y - 0.5) ** 2
    zone_plate = 0.5 + 0.5 * torch.cos(400 * radius2)
    chart = torch.stack([x, y, zone_plate])
    chart[:, : size // 8] = torch.floor(x[: size // 8] * 8) / 7
    return (chart.clamp(0, 1) * 255).round().to(torch.uint8)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", default="city100-iphonex", help=f"one of {list_profiles()} or a path")
    parser.add_argument("--out", type=Path, default=Path("out/demo"))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    profile = load_profile(args.profile)
    degrade = CameraDegrade(profile, seed=args.seed)
    images = sample_images()
    batch = torch.stack(list(images.values()))
    started = time.perf_counter()
    degraded = degrade(batch)
    seconds = time.perf_counter() - started

    difference = ((degraded.float() - batch.float()).abs() * 4).clamp(0, 255).to(torch.uint8)
    rows = torch.stack([batch, degraded, difference], dim=1).flatten(0, 1)
    grid_path = args.out / "grid.png"
    write_image(make_grid(rows, nrow=3, padding=4, pad_value=255), grid_path)

    summary = {
        "profile": profile.name,
        "description": profile.description,
        "effects": profile.effect_names,
        "profile_held_out_quality": profile.quality,
        "images": {
            name: {"psnr_degraded_vs_clean_db": round(psnr(degraded[i], batch[i]), 2)} for i, name in enumerate(images)
        },
        "seconds_for_batch": round(seconds, 3),
        "grid": str(grid_path),
    }
    (args.out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(profile_summary(args.profile))
    print()
    for name, stats in summary["images"].items():
        print(f"image {name:10s} PSNR(degraded, clean) = {stats['psnr_degraded_vs_clean_db']:.2f} dB")
    print(f"degraded {len(images)} images of {SIZE}x{SIZE} in {seconds:.2f} s")
    print(f"wrote {grid_path} (clean | degraded | |diff| x4) and {args.out / 'summary.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
