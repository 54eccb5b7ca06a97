"""The unpaired fit's detail-response rule (:func:`camdegrade.fitting.unpaired.steps.spectrum.fit_detail_response`) on
its own: a simulation whose mean spectrum moves by twice the log2 gain per band (power is amplitude squared), so
what the rule keeps and what it refuses is known exactly."""

from __future__ import annotations

import torch
from torch import Tensor

from camdegrade.fitting.unpaired.steps.spectrum import (
    RESPONSE_FLOOR,
    RESPONSE_LIMIT,
    fit_band_gains,
    fit_detail_response,
)

BANDS, IMAGES = 8, 16


def _spectra(seed: int, spread: float) -> Tensor:
    """``(IMAGES, BANDS)`` per-image spectra: a common slope and ``spread`` of content from image to image."""
    generator = torch.Generator().manual_seed(seed)
    slope = -torch.linspace(1.0, 15.0, BANDS, dtype=torch.float64)
    return slope + spread * torch.randn(IMAGES, BANDS, generator=generator, dtype=torch.float64)


def _simulator(cleans: Tensor):
    """``simulate(gains, part)``: the clean spectra of ``part``, their mean, moved by twice the log2 gains."""

    def simulate(gains: Tensor | None, part: slice) -> Tensor:
        mean = cleans[part].mean(0)
        return mean if gains is None else mean + 2 * gains

    return simulate


def test_a_camera_shape_in_both_halves_is_fitted_and_kept() -> None:
    shape = torch.tensor([0.4, 0.5, 0.3, -0.3, -0.6, 0.3, 0.0, -0.4], dtype=torch.float64)
    cleans = _spectra(0, 0.05)
    reals = _spectra(1, 0.05) + shape
    gains, notes = fit_detail_response(reals, _simulator(cleans))
    assert notes["kept"] and gains is not None, notes
    expected = (reals.mean(0) - cleans.mean(0)) / 2
    assert float((gains - expected).abs().max()) < 1e-9, (gains, expected)  # a linear response: one round
    assert notes["rounds"][0] == notes["mismatch_left"] and max(notes["rounds"][1:]) < 1e-9, notes
    assert notes["mismatch"] < 1e-9, notes


def test_content_that_differs_between_halves_is_not_kept() -> None:
    """Per-image content of 1 log2 and no camera shape: each half's response fits its own images' content, which
    the other half does not share."""
    cleans, reals = _spectra(0, 1.0), _spectra(1, 1.0)
    gains, notes = fit_detail_response(reals, _simulator(cleans))
    assert notes["mismatch_left"] > RESPONSE_FLOOR and notes["halves"], notes  # the check ran
    assert gains is None and notes["kept"] is False, notes


def test_a_mismatch_below_the_floor_is_not_fitted() -> None:
    cleans = _spectra(0, 0.01)
    reals = _spectra(1, 0.01) + 0.15  # a systematic 0.0225 mean-squared mismatch: in both halves
    gains, notes = fit_detail_response(reals, _simulator(cleans))
    assert 0.01 < notes["mismatch_left"] < RESPONSE_FLOOR, notes
    assert gains is None and notes == {"mismatch_left": notes["mismatch_left"], "halves": [], "kept": False}


def test_band_gains_stay_within_the_stage_range() -> None:
    """A simulation that never responds: the gains walk at most one log2 a round and stop at the stage's limit."""
    real = torch.full((BANDS,), 20.0, dtype=torch.float64)
    gains, mismatches = fit_band_gains(real, lambda gains: torch.zeros(BANDS, dtype=torch.float64), rounds=6)
    assert torch.equal(gains, torch.full((BANDS,), RESPONSE_LIMIT, dtype=torch.float64))
    assert mismatches == [400.0] * 6
