"""Diagnose the built-in ``city100-iphonex`` profile on its 16 held-out REAL City100 scenes (056–070, 098).

The profile was fitted on scenes 001–055, so these pairs are new to it. The diagnosis splits them by scene into
8 calibration and 8 held-out pairs, fits every candidate effect on top of the profile and reports what remains.
Pairs are centre-cropped to ``--crop`` pixels (the full frames are large; the crop keeps the run to minutes).

    OMP_NUM_THREADS=1 .venv/bin/python examples/diagnose_city100.py --out out/diagnose/city100
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from camdegrade.diagnose import diagnose
from camdegrade.fitting.pairs import discover_pairs, filter_pairs, load_pair

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real-pairs"
HELD_OUT = {f"{n:03d}" for n in range(56, 71)} | {"098"}


def held_out_pairs(data: Path, crop: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
    pairs = filter_pairs(discover_pairs(data / "pairs.csv").pairs, subset="city100_iPhoneX")
    out = []
    for pair in pairs:
        if pair.scene not in HELD_OUT:  # scene "001" for 001H.PNG / 001L.PNG
            continue
        clean, captured = load_pair(pair)
        height, width = clean.shape[-2:]
        side = min(crop, height, width)
        top, left = (height - side) // 2, (width - side) // 2
        out.append((clean[:, top : top + side, left : left + side], captured[:, top : top + side, left : left + side]))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--crop", type=int, default=384)
    parser.add_argument("--out", type=Path, default=Path("out/diagnose/city100"))
    args = parser.parse_args()
    torch.set_num_threads(1)
    pairs = held_out_pairs(args.data, args.crop)
    print(f"{len(pairs)} held-out City100 iPhone X pairs, centre {args.crop}px")
    report = diagnose("city100-iphonex", pairs, seed=0, log=print)
    args.out.mkdir(parents=True, exist_ok=True)
    report.write_json(args.out / "report.json")
    report.write_html(args.out / "report.html")
    for entry in report.where:
        print(f"{entry['axis']:>10s} {entry['score']:7.2f} (null {entry['null']:.2f})  {entry['finding']}")
    print(report.verdict)


if __name__ == "__main__":
    main()
