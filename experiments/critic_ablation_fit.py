"""What a small critic keys on when it tells a default fit from the City100 iPhone X (issue 23, item 0).

Each row changes one thing, either in the real captures (how sensitive is the critic to that change?) or in a
default-fit profile (does removing a suspect make the simulation harder to tell?), and re-runs the critic of
:mod:`camdegrade.measures.critic` on pairs it never trained on: the 16 held-out scenes (056–070, 098; never used
in any fit), whole frames, trained on the even ones and scored on the odd ones and the other way round, for
``--seeds`` critic seeds (a seed draws the patches, the critic's start and its minibatches). Every image is
rounded to 8 bits, as the captures are. Rows:

- the captures blurred (σ 0.5 px), sharpened (unsharp mask σ 1, amount 0.5), with white noise of 1 level added,
  and cored (``denoise_image``: σ 1, 2 levels): a change the critic cannot see stays near 0.5;
- the profile without its ``denoise`` stage (what a fit gave before that stage existed), the same with its chroma
  blurred (σ 2, the luma kept), its luma blurred (σ 0.5), and cored (σ 1, 2 levels);
- the profile as fitted, and that with an extra unsharp mask (σ 2, amount 0.7);
- the least-squares linear baseline (a 7×7 colour filter fitted on scenes 001–055).

It prints per row the mean accuracy over the critics (image-only: what a model trained on the simulation sees;
paired: it also sees the clean source) with their spread, :func:`~camdegrade.measures.measure_fidelity`'s grid
ratio and log2 band power sim/real, and the detail-amplitude distance the fit's noise-reduction step minimises
(:func:`~camdegrade.fitting.steps.denoise.amplitude_distance`, levels; 0: the captures' own) and the fine detail on
flat pixels (:func:`flat_fine_detail`: the std of the 8-bit luma minus its 3×3 mean on the clean image's flat
pixels, over the captures'). ``--no-critics``
prints the measures alone, in a minute or two. The profile comes from ``experiments/fit_city100_default.py``. Run
from the repo root::

    OMP_NUM_THREADS=2 .venv/bin/python experiments/fit_city100_default.py --out out/city100-default.safetensors
    OMP_NUM_THREADS=2 .venv/bin/python experiments/critic_ablation_fit.py --profile out/city100-default.safetensors

The critics are seeded, but torch trains them differently with another number of threads: keep
``OMP_NUM_THREADS=2`` to reproduce the numbers of docs/results.md.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade import CameraDegrade, CameraProfile, load_profile
from camdegrade._support.pixels import as_unit
from camdegrade.effects import Denoise
from camdegrade.fitting import discover_pairs, filter_pairs, load_pair
from camdegrade.fitting.network.baseline import apply_linear_baseline, fit_linear_baseline
from camdegrade.fitting.steps.denoise import amplitude_distance, detail_amplitudes
from camdegrade.functional import blur_image, denoise_image, unsharp_mask_image
from camdegrade.functional.analysis.images import flat_mask, luma
from camdegrade.measures.critic import critic_test
from camdegrade.measures.fidelity import measure_fidelity

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DATA = ROOT.parent / "shared" / "data" / "real-pairs"
TRAINING = [f"{n:03d}" for n in range(1, 56)]
HELD_OUT = sorted({f"{n:03d}" for n in range(56, 71)} | {"098"})
MODES = {"image-only": True, "paired": False}
#: The white noise added to the captures (8-bit levels) and the coring of the "cored" rows (σ px, levels).
NOISE_LEVELS = 1.0
CORING = (1.0, 2.0)

Row = Callable[[int, Tensor, Tensor], Tensor]


def city100_pairs(data: Path, scenes: list[str]) -> list[tuple[Tensor, Tensor]]:
    """``(clean, real)`` float in [0, 1] for the City100 iPhone X ``scenes``."""
    found = {p.scene: p for p in filter_pairs(discover_pairs(data / "pairs.csv").pairs, subset="city100_iPhoneX")}
    return [tuple(as_unit(image) for image in load_pair(found[scene])) for scene in scenes]


def eight_bit(image: Tensor) -> Tensor:
    return (image.clamp(0, 1) * 255).round() / 255


def flat_fine_detail(images: list[Tensor], cleans: list[Tensor]) -> tuple[float, int]:
    """The std (8-bit levels) of the 8-bit luma minus its 3×3 mean, over the pixels that are flat in the clean images
    (:func:`~camdegrade.functional.analysis.images.flat_mask`), and how many pixels that is."""
    squares, count = 0.0, 0
    for image, clean in zip(images, cleans, strict=True):
        gray = luma(eight_bit(image)) * 255.0
        mean = F.avg_pool2d(F.pad(gray[None, None], (1, 1, 1, 1), mode="replicate"), 3, stride=1)[0, 0]
        detail = (gray - mean)[flat_mask(clean)]
        squares, count = squares + float(detail.pow(2).sum()), count + detail.numel()
    return (squares / max(count, 1)) ** 0.5, count


def with_white_noise(image: Tensor, index: int) -> Tensor:
    generator = torch.Generator().manual_seed(index)
    return image + NOISE_LEVELS / 255 * torch.randn(image.shape, generator=generator)


def chroma_blurred(image: Tensor, sigma: float) -> Tensor:
    """The luma kept, the chroma (image − luma) blurred."""
    gray = luma(image)[None]
    return gray + blur_image(image - gray, sigma)


def luma_blurred(image: Tensor, sigma: float) -> Tensor:
    """The chroma kept, the luma blurred."""
    gray = luma(image)[None].expand(3, -1, -1)
    return image - gray + blur_image(gray, sigma)


def without_denoise(profile: CameraProfile) -> CameraProfile:
    return profile.with_chain([effect for effect in profile.effects if not isinstance(effect, Denoise)])


def rows_of(profile: CameraProfile, training: list[tuple[Tensor, Tensor]]) -> dict[str, Row]:
    """Every row: ``(scene index, clean, real) → image`` (float; rounded to 8 bits by the caller)."""
    plain = without_denoise(profile)
    weight, bias = fit_linear_baseline(training)

    def sampled(chosen: CameraProfile) -> Callable[[int, Tensor], Tensor]:
        return lambda index, clean: CameraDegrade(chosen, seed=index)(clean).clamp(0, 1)

    fitted, before = sampled(profile), sampled(plain)
    return {
        "capture blurred σ 0.5": lambda i, c, r: blur_image(r, 0.5),
        "capture + unsharp σ 1 × 0.5": lambda i, c, r: unsharp_mask_image(r, 1.0, 0.5),
        f"capture + white noise {NOISE_LEVELS:g} level": lambda i, c, r: with_white_noise(r, i),
        "capture cored": lambda i, c, r: denoise_image(r, CORING[0], CORING[1] / 255),
        "profile without denoise": lambda i, c, r: before(i, c),
        "profile without denoise, chroma blurred σ 2": lambda i, c, r: chroma_blurred(before(i, c), 2.0),
        "profile without denoise, luma blurred σ 0.5": lambda i, c, r: luma_blurred(before(i, c), 0.5),
        "profile without denoise, cored": lambda i, c, r: denoise_image(before(i, c), CORING[0], CORING[1] / 255),
        "profile (fitted denoise)": lambda i, c, r: fitted(i, c),
        "profile + unsharp σ 2 × 0.7": lambda i, c, r: unsharp_mask_image(fitted(i, c), 2.0, 0.7),
        "linear baseline (7×7)": lambda i, c, r: apply_linear_baseline(weight, bias, c[None])[0],
    }


def critic_scores(cleans: list[Tensor], reals: list[Tensor], sims: list[Tensor], seeds: int) -> dict[str, list]:
    """Per mode, the accuracy of every critic: each seed, both folds (even scenes train, odd score; and back)."""
    even, odd = slice(0, None, 2), slice(1, None, 2)
    scores: dict[str, list[float]] = {}
    for mode, image_only in MODES.items():
        for seed in range(seeds):
            for fit, check in ((even, odd), (odd, even)):
                result = critic_test(
                    (cleans[fit], reals[fit], sims[fit]),
                    (cleans[check], reals[check], sims[check]),
                    seed,
                    image_only=image_only,
                )
                scores.setdefault(mode, []).append(round(result.accuracy, 4))
    return scores


def _cell(values: list[float]) -> str:
    if not values:
        return "—"
    spread = statistics.stdev(values) if len(values) > 1 else 0.0
    return f"{statistics.mean(values):.3f} ± {spread:.3f}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--profile", type=Path, required=True, help="a default fit (experiments/fit_city100_default.py)"
    )
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--seeds", type=int, default=3, help="critic seeds per row and mode (default 3)")
    parser.add_argument("--no-critics", dest="critics", action="store_false", help="the measures alone")
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "results" / "critic_ablation_fit.json")
    args = parser.parse_args(argv)
    if not (args.data / "pairs.csv").is_file():
        parser.error(f"no pairs.csv in {args.data}; pass --data with the real-pairs folder")
    if args.seeds < 1:
        parser.error(f"--seeds must be positive, got {args.seeds}")
    started = time.perf_counter()
    profile = load_profile(args.profile)
    held = city100_pairs(args.data, HELD_OUT)
    cleans, reals = [clean for clean, _ in held], [real for _, real in held]
    rows = rows_of(profile, city100_pairs(args.data, TRAINING))
    print(f"profile stages: {[type(effect).__name__ for effect in profile.effects]}", flush=True)
    real_amplitudes = detail_amplitudes(reals)
    real_fine, flat_pixels = flat_fine_detail(reals, cleans)
    print(f"captures' fine detail on {flat_pixels} flat pixels: {real_fine:.3f} levels")
    print(
        "| row | image-only | paired | grid ratio | log2 band power sim/real | detail-amplitude distance "
        "| flat fine detail / capture's |"
    )
    print("|---|---|---|---|---|---|---|")
    record = {}
    for name, row in rows.items():
        with torch.no_grad():
            sims = [eight_bit(row(index, clean, real)) for index, (clean, real) in enumerate(held)]
        fidelity = measure_fidelity(sims, reals, cleans)
        distance = amplitude_distance(detail_amplitudes(sims), real_amplitudes)
        fine = flat_fine_detail(sims, cleans)[0] / real_fine
        scores = critic_scores(cleans, reals, sims, args.seeds) if args.critics else {mode: [] for mode in MODES}
        bands = " / ".join("n/a" if b is None else f"{b:+.2f}" for b in fidelity.bands)
        print(
            f"| {name} | {_cell(scores['image-only'])} | {_cell(scores['paired'])} | {fidelity.grid_ratio:.2f} "
            f"| {bands} | {distance:.2f} | {fine:.2f} |",
            flush=True,
        )
        record[name] = {
            "critics": scores,
            "fidelity": fidelity.to_dict(),
            "amplitude_distance": round(distance, 4),
            "flat_fine_detail_ratio": round(fine, 4),
        }
    seconds = time.perf_counter() - started
    print(f"{len(rows) * len(MODES) * 2 * args.seeds * args.critics} critics; {seconds:.0f} s in all")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"rows": record, "seconds": round(seconds, 1)}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
