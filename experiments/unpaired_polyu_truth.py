"""Issue 43's PolyU unpaired case (``experiments/unpaired_polyu_noise.py``) read against the truth the fit never sees.

The fit: 10 PolyU captures (Canon 5D Mk II, 128² crops saved as JPEG q85) beside 89 other scenes' mean frames. Here:

1. **Per-bin noise against the oracle's distance** (issue 27's table, ``experiments/noise_table_unpaired.py``): the
   profile is simulated on the mean frames of the 19 *other* Canon 5D Mk II shots (whole 512² frames, their noisy
   shots saved as JPEG q85 like the captures; the fit saw none of these captures) and its noise, per channel and
   intensity bin where the mean frame is flat, is divided by the real noise of those shots. The oracle: the 10
   captures' own real noise (each against its mean frame) over the same. Printed: median / worst ``|log2|`` of
   each, and the bins where the profile is within the oracle's worst.
2. **The own check on the true clean images**: ``unpaired_fidelity`` of the profile with the captures' own mean
   frames as the clean set (the same scenes: content cannot differ), beside the fit's own check (other scenes), and
   the same with parts of the profile (no stage, noise only, tone only).
3. **The check's own spread**: each band's split-half standard error (``band_spread`` in the own check, random
   halves of the captures and of the simulated clean crops, :func:`~camdegrade.fitting.unpaired.judges.band_spread`):
   what content alone moves the band reading by at this sample size, and the fit's notes on it.

Run from the repo root::

    OMP_NUM_THREADS=1 .venv/bin/python experiments/unpaired_polyu_truth.py [REAL_PAIRS_DIR] [--without color,tone]
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import tempfile
from pathlib import Path

import torch
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parent))

from noise_table import _residual_sums
from unpaired_polyu_noise import CAPTURES, _scene, default_real_pairs_dir, write_sets

from camdegrade import CameraProfile
from camdegrade._support.pixels import as_unit
from camdegrade.fitting.unpaired import UNPAIRED_EFFECTS, fit_unpaired, unpaired_fidelity
from camdegrade.io import read_image

CAMERA = "Canon5D2"


def held_out_pairs(root: Path, folder: Path) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
    """The mean frames and the noisy shots (saved as JPEG q85, read back) of the Canon 5D Mk II pairs after the
    first :data:`CAPTURES` (whole frames)."""
    with open(root / "pairs.csv", newline="") as handle:
        rows = sorted(
            (r for r in csv.DictReader(handle) if r["subset"] == "polyu_real_noise"), key=lambda r: r["clean"]
        )
    rows = [row for row in rows[CAPTURES:] if _scene(row["clean"]).startswith(CAMERA)]
    folder.mkdir()
    cleans, reals = [], []
    for index, row in enumerate(rows):
        Image.open(root / row["captured"]).convert("RGB").save(folder / f"{index:02d}.jpg", quality=85)
        cleans.append(as_unit(read_image(root / row["clean"])).float())
        reals.append(as_unit(read_image(folder / f"{index:02d}.jpg")).float())
    return cleans, reals


def _spread(ratio: torch.Tensor) -> tuple[float, float, int]:
    values = ratio.flatten()
    values = values[torch.isfinite(values) & (values > 0)].log2().abs()
    return round(float(values.median()), 3), round(float(values.max()), 3), int(values.numel())


def per_bin_rows(profile: CameraProfile, captured: Path, means: list[Path], root: Path, scratch: Path) -> dict:
    """Item 1 of the module: the profile's and the oracle's per-bin ``|log2|`` against the held-out real noise."""
    cleans, reals = held_out_pairs(root, scratch / "held_out")
    real = _residual_sums(reals, cleans).std()
    sims = profile.simulate(cleans, 1, stream="truth", eight_bit=True)
    fitted = _residual_sums(sims, cleans).std() / real
    captures = [as_unit(read_image(captured / f"{path.stem}.jpg")).float() for path in means]
    mean_frames = [as_unit(read_image(path)).float() for path in means]
    oracle = _residual_sums(captures, mean_frames).std() / real
    both = torch.isfinite(fitted) & torch.isfinite(oracle)
    oracle_worst = float(oracle[both].log2().abs().max())
    within = int((fitted[both].log2().abs() <= oracle_worst).sum())
    per_bin = int((fitted[both].log2().abs() <= oracle[both].log2().abs()).sum())
    return {
        "held_out_pairs": len(cleans),
        "profile": _spread(fitted),
        "oracle": _spread(oracle),
        "bins_within_oracle_worst": f"{within} of {int(both.sum())}",
        "bins_at_most_oracle_same_bin": f"{per_bin} of {int(both.sum())}",
        "profile_log2": [[round(float(v), 2) for v in row] for row in fitted.log2()],
        "oracle_log2": [[round(float(v), 2) for v in row] for row in oracle.log2()],
    }


def _parts(profile: CameraProfile) -> dict[str, CameraProfile]:
    stages = {effect.name: effect for effect in profile.effects}
    parts = {"whole profile": profile, "no stage": CameraProfile(None, [])}
    for name in stages:
        parts[f"{name} only"] = CameraProfile(None, [stages[name]])
    return parts


def measure(root: Path, without: tuple[str, ...] = ()) -> dict:
    """Fit the case (``without`` these stages) and return the three readings of the module."""
    with tempfile.TemporaryDirectory() as scratch_name:
        scratch = Path(scratch_name)
        captured, clean, means = write_sets(root, scratch)
        profile = fit_unpaired(captured, clean, effects=[e for e in UNPAIRED_EFFECTS if e not in without], seed=0)
        out = {"kept": profile.effect_names, "records": profile.fitted["effects"]}
        out["own check"] = profile.quality["unpaired_fidelity"]
        out["warnings"], out["notes"] = profile.fitted.get("warnings", []), profile.fitted.get("notes", [])
        out["per bin"] = per_bin_rows(profile, captured, means, root, scratch)
        out["true clean"] = {
            label: unpaired_fidelity(part, captured, scratch / "captured_mean")
            for label, part in _parts(profile).items()
        }
        out["clean set, no stage"] = unpaired_fidelity(CameraProfile(None, []), captured, clean)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("root", nargs="?", type=Path, default=default_real_pairs_dir())
    parser.add_argument("--without", default="", help="stages not to fit, comma-separated (e.g. color,tone)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    result = measure(args.root, tuple(name for name in args.without.split(",") if name))
    for key, value in result.items():
        print(f"{key}: {json.dumps(value)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
