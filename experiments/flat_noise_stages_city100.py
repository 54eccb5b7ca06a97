"""Where an unpaired City100 profile's flat noise comes from (issue 43): the held-out scenes' flat pixels (as
:func:`camdegrade.measures.fidelity.measure_fidelity` reads them: the clean image flat, pixels the image clips left
out) of the captures, of the clean images and of the profile with one or more of its stages left out. Printed per
row: the pooled noise std (8-bit levels), the pixels it rests on, and the std per bin of clean value with the bin's
pixels. Run from the repo root::

    OMP_NUM_THREADS=1 .venv/bin/python experiments/fit_city100_unpaired.py --out /tmp/c100.safetensors
    OMP_NUM_THREADS=1 .venv/bin/python experiments/flat_noise_stages_city100.py /tmp/c100.safetensors [--data DIR]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from fit_city100_unpaired import DEFAULT_DATA, HELD_OUT, city100

from camdegrade import CameraProfile, load_profile
from camdegrade._support.pixels import as_unit
from camdegrade.functional.analysis.images import flat_mask
from camdegrade.functional.analysis.noise import MIN_PIXELS, NoiseSums
from camdegrade.measures.fidelity import quiet_masks

#: The stages left out, row by row (a row is printed only where the profile has every one of them).
LEFT_OUT = (
    (),
    ("noise",),
    ("learned_texture",),
    ("noise", "learned_texture"),
    ("frequency_response",),
    ("sharpen",),
    ("sharpen", "frequency_response"),
    ("noise", "sharpen", "frequency_response", "learned_texture"),
)


def sums(images, cleans, masks) -> NoiseSums:
    total = NoiseSums.zeros()
    for image, clean, mask in zip(images, cleans, masks, strict=True):
        total = total + NoiseSums.measure(image.float(), clean, mask)
    return total


def line(label: str, measured: NoiseSums) -> str:
    counts = measured.count.sum(0) / 3
    levels = measured.std(MIN_PIXELS).pow(2).mean(0).sqrt()  # NaN where a channel's bin has too few pixels
    bins = " / ".join(
        f"{float(level):.2f} ({int(count)})" if math.isfinite(float(level)) else "–"
        for level, count in zip(levels, counts, strict=True)
    )
    return f"| {label} | {measured.pooled_std():.3f} ({measured.pixels}) | {bins} |"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("profile", type=Path)
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    args = parser.parse_args()
    profile, scenes = load_profile(args.profile), city100(args.data)
    cleans = [as_unit(scenes[scene][0]) for scene in HELD_OUT]
    reals = [as_unit(scenes[scene][1]) for scene in HELD_OUT]
    masks = quiet_masks(cleans, [flat_mask(clean) for clean in cleans])
    print(f"chain: {profile.effect_names}")
    print("| held-out flat pixels | pooled std (pixels) | std by bin of clean value (pixels) |\n|---|---|---|")
    captured = sums(reals, cleans, masks)
    print(line("captures", captured))
    print(line("clean images", sums(cleans, cleans, masks)))
    for left_out in LEFT_OUT:
        if not all(name in profile.effect_names for name in left_out):
            continue
        chain = CameraProfile(None, [effect for effect in profile.effects if effect.name not in left_out])
        sims = [image.mul(255).round().div(255) for image in chain.simulate(cleans, 0)]
        measured = sums(sims, cleans, masks)
        label = "the profile" + (f" less {' + '.join(left_out)}" if left_out else "")
        print(line(f"{label} (ratio {measured.pooled_std() / captured.pooled_std():.2f})", measured))


if __name__ == "__main__":
    main()
