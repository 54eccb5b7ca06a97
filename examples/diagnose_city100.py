"""Diagnose a City100 profile on its 16 held-out REAL City100 scenes (056–070, 098).

The built-in ``city100-iphonex`` was fitted on scenes 001–055, so these pairs are new to it. The diagnosis splits
them by scene into 8 calibration and 8 held-out pairs, tries every change (add, remove, refit a stage, refit the
network) on top of the profile and reports what remains, with the learned critic. Whole frames by default (the noise
is measured where the clean image is flat, and a city scene's flat regions are few); ``--crop`` takes centre crops.
``--profile`` diagnoses another profile, e.g. the one shipped before the flat-region noise fit (a test fixture).

    OMP_NUM_THREADS=2 .venv/bin/python examples/diagnose_city100.py --out out/diagnose/city100
    OMP_NUM_THREADS=2 .venv/bin/python examples/diagnose_city100.py \
        --profile tests/fixtures/city100-iphonex-2026-11-23.safetensors --out out/diagnose/city100-before
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from camdegrade.diagnose import diagnose
from camdegrade.fitting import discover_pairs, filter_pairs, load_pair

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real-pairs"
HELD_OUT = {f"{n:03d}" for n in range(56, 71)} | {"098"}


def held_out_pairs(data: Path, crop: int | None = None) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """The held-out pairs (uint8), whole or centre-cropped to ``crop`` pixels."""
    pairs = filter_pairs(discover_pairs(data / "pairs.csv").pairs, subset="city100_iPhoneX")
    out = []
    for pair in pairs:
        if pair.scene not in HELD_OUT:  # scene "001" for 001H.PNG / 001L.PNG
            continue
        clean, captured = load_pair(pair)
        if crop:
            height, width = clean.shape[-2:]
            side = min(crop, height, width)
            top, left = (height - side) // 2, (width - side) // 2
            window = (slice(None), slice(top, top + side), slice(left, left + side))
            clean, captured = clean[window], captured[window]
        out.append((clean, captured))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--crop", type=int, default=None, help="centre crops of this size (default: whole frames)")
    parser.add_argument("--profile", default="city100-iphonex", help="built-in name or .safetensors path")
    parser.add_argument("--out", type=Path, default=Path("out/diagnose/city100"))
    args = parser.parse_args()
    pairs = held_out_pairs(args.data, args.crop)
    print(f"{len(pairs)} held-out City100 iPhone X pairs, {f'centre {args.crop}px' if args.crop else 'whole frames'}")
    report = diagnose(args.profile, pairs, seed=0, log=print)
    args.out.mkdir(parents=True, exist_ok=True)
    report.write_json(args.out / "report.json")
    report.write_html(args.out / "report.html")
    for entry in report.where:
        print(f"{entry['axis']:>10s} {entry['score']:7.2f} (null {entry['null']:.2f})  {entry['finding']}")
    for entry in report.visible:  # what a person sees: the network's grid, the texture
        said = "significant" if entry["significant"] else "not significant"
        print(f"{entry['look']:>10s} {said}: {entry['finding']}")
        if "after_finding" in entry:
            print(f"{'':>10s} after the changes: {entry['after_finding']}")
    print(report.verdict)


if __name__ == "__main__":
    main()
