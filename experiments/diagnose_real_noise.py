"""Diagnose a profile with no noise stage on REAL sensor noise: PolyU, CC15 and SIDD.

Clean = the mean of many frames, captured = one frame of the same scene, so the gap is the camera's noise and
nothing else. Each pair is cut to its 256² window with the most flat pixels (noise is measured only where the clean
image is flat in absolute terms). The diagnosis must name the missing noise, and the profile it returns must give
the flat-pixel noise the captures show. Prints one table row per subset (the numbers in docs/diagnosis.md):

    OMP_NUM_THREADS=1 .venv/bin/python experiments/diagnose_real_noise.py

``tests/test_diagnose_realdata.py`` runs the same selection and asserts the outcome.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch
from torch import Tensor

from camdegrade.diagnose import DiagnosisReport, diagnose
from camdegrade.fitting import discover_pairs, filter_pairs, load_pair
from camdegrade.functional.analysis.images import flat_mask, flattest_window
from camdegrade.functional.analysis.noise import measure_set
from camdegrade.profile import CameraProfile

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real-pairs"
#: subset → at most this many pairs (evenly chosen).
SUBSETS = {"polyu_real_noise": 24, "cc15_nam_real_noise": 15, "sidd_samples": 12}
SIDE = 256
CANDIDATES = ("noise", "blur", "jpeg")


def subset_pairs(data: Path, subset: str, count: int | None = None) -> list[tuple[Tensor, Tensor]]:
    """Up to ``count`` pairs of ``subset`` (evenly chosen, default :data:`SUBSETS`), as floats in [0, 1], each cut
    to its flattest ``SIDE``² window."""
    count = SUBSETS[subset] if count is None else count
    pairs = filter_pairs(discover_pairs(data / "pairs.csv").pairs, subset=subset)
    pairs = pairs[:: max(1, len(pairs) // count)][:count]
    out = []
    for pair in pairs:
        clean, captured = (image.float() / 255 for image in load_pair(pair))
        window, _ = flattest_window(clean, SIDE)
        out.append((clean[(slice(None), *window)], captured[(slice(None), *window)]))
    return out


def diagnose_without_noise(pairs: list[tuple[Tensor, Tensor]], seed: int = 0) -> DiagnosisReport:
    """The diagnosis of a profile with no stages at all (no critic: the statistics are what is checked here)."""
    return diagnose(CameraProfile(None, [], name="no-noise"), pairs, candidates=CANDIDATES, seed=seed, critic=False)


def flat_noise(profile: CameraProfile, pairs: list[tuple[Tensor, Tensor]], seed: int = 1) -> tuple[float, float, int]:
    """(captures', simulations') pooled flat-pixel noise std in 8-bit levels, and the flat pixels they rest on."""
    cleans, reals = [clean for clean, _ in pairs], [real for _, real in pairs]
    masks = [flat_mask(clean) for clean in cleans]
    real = measure_set(reals, cleans, masks)
    simulated = measure_set(profile.simulate(cleans, seed), cleans, masks)
    return real.pooled_std(), simulated.pooled_std(), int(sum(int(mask.sum()) for mask in masks))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    args = parser.parse_args()
    if not (args.data / "pairs.csv").is_file():
        parser.error(f"no pairs.csv in {args.data}; pass --data with the real-pairs folder")
    torch.set_num_threads(1)
    print(
        "| subset | pairs (cal/held) | first accepted | gap before → after (floor) | closed "
        "| flat px | real std | sim std | ratio | largest families after | s |"
    )
    print("|---|---|---|---|---:|---:|---:|---:|---:|---|---:|")
    for subset in SUBSETS:
        start = time.perf_counter()
        pairs = subset_pairs(args.data, subset)
        report = diagnose_without_noise(pairs)
        real, simulated, pixels = flat_noise(report.profile, pairs)
        first = report.accepted[0] if report.accepted else "none"
        after = sorted(report.families_after.items(), key=lambda item: -item[1])[:3]
        largest = ", ".join(f"{name} {score:.1f}" for name, score in after)
        print(
            f"| {subset} | {report.calibration_pairs}/{report.held_out_pairs} | {first} | "
            f"{report.gap_before:.2f} → {report.gap_after:.2f} ({report.noise_floor:.2f}) | "
            f"{report.fraction_closed:.0%} | {pixels:,} | {real:.2f} | {simulated:.2f} | {simulated / real:.2f} | "
            f"{largest} | {time.perf_counter() - start:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
