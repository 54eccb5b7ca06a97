"""Diagnose a City100 profile on its 16 held-out REAL City100 scenes (056–070, 098).

The built-in ``city100-iphonex`` was fitted on scenes 001–055, so these pairs are new to it. The diagnosis splits
them by scene into 8 calibration and 8 held-out pairs, tries every change (add, remove, refit a stage, refit the
network) on top of the profile and reports what remains, with the learned critic. Whole frames by default (the noise
is measured where the clean image is flat, and a city scene's flat regions are few); ``--crop`` takes centre crops.
``--profile`` diagnoses another profile, e.g. the one shipped before the flat-region noise fit (a test fixture).
``--fresh-critics N`` checks the reported critics after the changes: 2N critics of each kind the diagnosis did not
train (N seeds, each both ways of an alternate split of the held-out pairs, on a new draw of the changed profile's
simulations), whose mean should fall in the report's interval.

    OMP_NUM_THREADS=2 .venv/bin/python experiments/diagnose_city100.py --out out/diagnose/city100
    OMP_NUM_THREADS=2 .venv/bin/python experiments/diagnose_city100.py \
        --profile tests/fixtures/city100-iphonex-2026-11-23.safetensors --out out/diagnose/city100-before
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from camdegrade._support.pixels import as_unit
from camdegrade.diagnose import diagnose
from camdegrade.fitting import discover_pairs, filter_pairs, load_pair
from camdegrade.measures.critic import repeated_critic_test

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
    parser.add_argument("--fresh-critics", type=int, default=0, help="confirm the critics after the changes")
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
    if args.fresh_critics:
        fresh_critics(report, pairs, args.fresh_critics)


def fresh_critics(report, pairs: list[tuple[torch.Tensor, torch.Tensor]], count: int) -> None:
    """Critics the diagnosis did not train, on the held-out pairs, against the profile with the changes: each kind's
    mean and whether it lies in the interval the report gives."""
    names = sorted(report.critic["after"]["scored_on"], key=int)  # the held-out pairs, named by their index
    cleans = [as_unit(pairs[int(name)][0]) for name in names]
    reals = [as_unit(pairs[int(name)][1]) for name in names]
    sims = [(s.clamp(0, 1) * 255).round() / 255 for s in report.profile.simulate(cleans, seed=1, stream="fresh")]
    for label, image_only in (("after", False), ("after (image only)", True)):
        reported = report.critic[label]
        spread = repeated_critic_test((cleans, reals, sims), names, count, image_only=image_only)
        inside = reported["low"] <= spread.accuracy <= reported["high"]
        print(
            f"fresh critics, {label}: {spread.accuracy:.3f} ± {spread.std:.3f} over {len(spread.accuracies)} critics; "
            f"the report: {reported['accuracy']:.3f} [{reported['low']:.3f}–{reported['high']:.3f}] -> "
            + ("within its interval" if inside else "OUTSIDE its interval")
        )


if __name__ == "__main__":
    main()
