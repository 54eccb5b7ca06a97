"""What the unpaired fit recovers of a simulated camera (the table in docs/fitting.md, 'Unpaired fitting').

The cameras of ``tests/test_unpaired_fit.py``: 16 dead-leaves scenes of 128² with three grey cards each are
photographed by a camera made of camdegrade effects at known strengths; the fit sees those captures and 16 *other*
scenes as the clean set. Rows: the combined camera (blur, vignetting, noise, white balance, tone curve), a
sharpening camera, a tone-curve camera, a camera that upscales from half its pixels (fitted with and without the
``resolution`` stage), a camera with a detail response blur and sharpening cannot make (24 scenes of 256²), one with
blur alone (192²), and the control (no effect). Run from the repo root::

    OMP_NUM_THREADS=1 .venv/bin/python experiments/unpaired_recovery.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from camdegrade import VirtualCamera
from camdegrade._support.seeds import derived_generator
from camdegrade.effects import Blur, Color, FrequencyResponse, Noise, Sharpen, Tone, Vignetting
from camdegrade.fitting.unpaired import UNPAIRED_EFFECTS, fit_unpaired
from camdegrade.functional.isp.tone import tone_curve
from test_unpaired_fit import COUNT, DETAIL_COUNT, DETAIL_SIZE, NO_DETAIL_SIZE, _captures, _scenes, _stage


def _grey_error(tone) -> float:
    grid = torch.linspace(0.1, 0.9, 9, dtype=torch.float64)
    values = (getattr(tone, key).double() for key in ("gamma", "black", "white", "exposure"))
    return float((tone_curve(grid, *values) - grid**1.3).abs().max())


def _upscale_rows(clean: list[torch.Tensor]) -> list[str]:
    """The camera of ``test_an_upscale_is_recovered_from_other_scenes``: lens blur σ 0.8, half the pixels, upscaled;
    fitted with and without the resolution stage."""
    camera = VirtualCamera([Blur(0.8)], scale=0.5)
    with torch.no_grad():
        captures = [camera(scene, generator=derived_generator(7, "capture", i)) for i, scene in enumerate(_scenes(2))]
    rows = []
    for effects in (("resolution", "blur", "sharpen"), ("blur", "sharpen")):
        profile = fit_unpaired(captures, clean, effects=effects)
        scale = _stage(profile, "resolution")
        blur = _stage(profile, "blur")
        bands = " / ".join(f"{v:+.2f}" for v in profile.quality["unpaired_fidelity"]["bands"])
        label = "upscale (2x)" if "resolution" in effects else "upscale, fitted without `resolution`"
        rows.append(
            f"| {label} | sensor scale; blur sigma; band log2 | 0.5; 0.8 px; 0 | "
            f"{float(scale.scale) if scale else 1:.2f}; {float(blur.sigma_x) if blur else 0:.2f} px; {bands} | "
            + ("exact; ≤ 1.2 px; ±0.65 |" if "resolution" in effects else "(not tested) |")
        )
    return rows


def _detail_rows() -> list[str]:
    """The cameras of ``test_a_detail_response_...`` (blur σ 0.8, 4 levels of noise and a radial detail response: a
    dip at 0.2 cycles/pixel, a rise at 0.3; 24 scenes of 256²) and ``test_no_detail_response_is_kept_where_blur_...``
    (blur σ 0.8 alone; 16 scenes of 192²)."""
    detail = FrequencyResponse.from_radial([0.05, 0.12, 0.2, 0.3, 0.45], [1.0, 1.3, 0.6, 1.4, 1.0], knots=21)
    noise = Noise(levels=torch.full((3, 4), 4.0 / 255), linear=False)
    cameras = (
        ("detail response (with blur and noise; 256²)", (Blur(0.8), noise, detail), DETAIL_COUNT, DETAIL_SIZE),
        ("blur alone (192²)", (Blur(0.8),), COUNT, NO_DETAIL_SIZE),
    )
    rows = []
    for label, camera, count, size in cameras:
        kinds = UNPAIRED_EFFECTS if len(camera) > 1 else ("blur", "sharpen", "frequency_response")
        profile = fit_unpaired(_captures(*camera, count=count, size=size), _scenes(1, count, size), effects=kinds)
        notes, fidelity = profile.fitted["effects"]["frequency_response"], profile.quality["unpaired_fidelity"]
        bands = " / ".join(f"{v:+.2f}" for v in fidelity["bands"])
        has = len(camera) > 1
        tested = "kept, mismatch below half of what is left, bands ±0.4, noise ±10 %" if has else "not kept"
        rows.append(
            f"| {label} | response kept; mismatch left → after; band log2; flat-noise ratio | "
            f"{'yes' if has else 'no'}; –; 0; 1 | {'yes' if notes['kept'] else 'no'}; {notes['mismatch_left']:.3f} → "
            f"{notes.get('mismatch', notes['mismatch_left']):.3f}; {bands}; {fidelity['noise_ratio']:.2f} | {tested} |"
        )
    return rows


def main() -> int:
    torch.set_num_threads(1)
    clean = _scenes(1)
    rows = ["| camera | stage | true | recovered | tolerance (tested) |", "|---|---|---|---|---|"]
    combined = fit_unpaired(
        _captures(
            Blur(1.5),
            Vignetting(-0.4),
            Noise(levels=torch.full((3, 4), 4.0 / 255), linear=False),
            Color(torch.diag(torch.tensor([1.25, 1.0, 0.8]))),
            Tone(gamma=1.3),
        ),
        clean,
    )
    gains = _stage(combined, "color").matrix.diagonal()
    vignetting = _stage(combined, "vignetting")
    fidelity = combined.quality["unpaired_fidelity"]
    rows += [
        f"| combined | blur sigma | 1.5 px | {float(_stage(combined, 'blur').sigma_x):.2f} px | ±0.5 px |",
        f"| combined | vignetting corner gain | 0.60 | {1 + float(vignetting.k1 + vignetting.k2):.2f} | ±0.1 |",
        f"| combined | noise std at mid-grey | 4.0 levels | {_stage(combined, 'noise').magnitude():.2f} levels "
        "| ±20 % |",
        f"| combined | flat-noise ratio sim/capture | 1 | {fidelity['noise_ratio']:.2f} | 0.8–1.25 |",
        f"| combined | white balance R/G, B/G | 1.25, 0.80 | {float(gains[0] / gains[1]):.2f}, "
        f"{float(gains[2] / gains[1]):.2f} | ±0.08 |",
        f"| combined | band log2 sim/capture | 0 | {' / '.join(f'{v:+.2f}' for v in fidelity['bands'])} | ±0.5 |",
    ]
    sharpened = fit_unpaired(_captures(Sharpen(1.0, 1.0)), clean, effects=("sharpen", "blur"))
    amount = _stage(sharpened, "sharpen")
    rows.append(
        f"| sharpening | unsharp amount | 1.0 | {float(amount.amount) if amount else 0:.2f} (blur: "
        f"{'none' if _stage(sharpened, 'blur') is None else 'fitted'}) | ±0.5, no blur |"
    )
    toned = fit_unpaired(_captures(Tone(gamma=1.3)), clean, effects=("color", "tone"))
    rows.append(
        f"| tone curve | max error of the curve on 0.1–0.9 | 0 | {_grey_error(_stage(toned, 'tone')):.3f} "
        f"(stages: {', '.join(toned.effect_names)}) | ≤ 0.05, no colour |"
    )
    rows += _upscale_rows(clean)
    rows += _detail_rows()
    control = fit_unpaired(_captures(), clean)
    rows.append(f"| control | stages kept | none | {', '.join(control.effect_names) or 'none'} | none |")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
