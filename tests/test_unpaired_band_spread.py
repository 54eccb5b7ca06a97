"""The unpaired fit's own check says which bands it cannot measure (issue 43): each band's reading comes with its
split-half standard error, what the two sets' content alone moves it by. On ten 128² PolyU crops beside 24 clean
crops that is 0.77–1.54 log2 (``experiments/unpaired_polyu_truth.py``), so a band beyond ±1 there may be content:
the check says "not measurable" with the spread instead of warning, and still warns where the spread is small."""

from __future__ import annotations

import torch

from camdegrade.fitting.unpaired import fit_unpaired
from camdegrade.fitting.unpaired.judges import band_spread, self_check_warnings, unmeasured_bands
from camdegrade.synthetic import dead_leaves_images

EDGES = [0.02, 0.08, 0.16, 0.25, 0.35, 0.5]
BANDS = [-1.15, -0.2, 0.3, 0.4, 1.05]


def test_a_band_content_moves_past_the_gate_is_a_note_not_a_warning() -> None:
    wide = {"noise_ratio": 1.0, "bands": BANDS, "band_edges": EDGES, "band_spread": [1.54, 1.15, 0.85, 0.86, 0.77]}
    assert self_check_warnings(wide, ["noise", "blur"], with_clean=True) == []
    (note,) = unmeasured_bands(wide, ["noise", "blur"], with_clean=True)
    assert "not measurable" in note and "0.02–0.08 cycles/pixel -1.15 ± 1.54" in note
    assert "0.35–0.5 cycles/pixel +1.05 ± 0.77" in note
    narrow = {**wide, "band_spread": [0.1] * 5}
    (warning,) = self_check_warnings(narrow, ["noise", "blur"], with_clean=True)
    assert "0.02–0.08 cycles/pixel -1.15" in warning and "0.35–0.5 cycles/pixel +1.05" in warning
    assert unmeasured_bands(narrow, ["noise", "blur"], with_clean=True) == []
    mixed = {**wide, "band_spread": [0.1, 0.1, 0.1, 0.1, 0.5]}  # the top band alone cannot be measured
    (warning,) = self_check_warnings(mixed, ["noise", "blur"], with_clean=True)
    assert "-1.15" in warning and "+1.05" not in warning
    assert "+1.05 ± 0.50" in unmeasured_bands(mixed, ["noise", "blur"], with_clean=True)[0]
    assert unmeasured_bands(wide, ["noise"], with_clean=True) == []  # no detail stage fitted: no band judged
    assert unmeasured_bands(wide, ["noise", "blur"], with_clean=False) == []


def test_band_spread_is_what_content_moves_the_reading_by() -> None:
    generator = torch.Generator().manual_seed(0)
    same = torch.full((10, 5), 3.0), torch.full((24, 5), 2.0)
    assert band_spread(*same, seed=0) == [0.0] * 5
    few = torch.randn(10, 5, generator=generator) * 2, torch.randn(24, 5, generator=generator) * 2
    many = torch.randn(400, 5, generator=generator) * 2, torch.randn(960, 5, generator=generator) * 2
    assert min(band_spread(*few, seed=0)) > 0.2 and max(band_spread(*many, seed=0)) < 0.2
    assert band_spread(*few, seed=0) == band_spread(*few, seed=0)


def test_the_fit_records_each_bands_spread() -> None:
    scenes = [image.float() / 255 for image in dead_leaves_images(8, 64, seed=3)]
    fidelity = fit_unpaired(scenes, effects=("vignetting",)).quality["unpaired_fidelity"]
    assert len(fidelity["band_spread"]) == len(fidelity["bands"]) == 5
    assert all(value > 0 for value in fidelity["band_spread"]), fidelity
