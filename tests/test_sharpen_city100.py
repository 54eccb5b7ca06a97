"""The sharpen stage on the REAL City100 iPhone X captures over the paper-network built-in (``PAPER_BUILT_IN``)
(``experiments/sharpen_city100.py`` measures it on every scene): fitted on 8 of scenes 001–055 against the built-in's
deterministic output, it finds a gentle, wide sharpening and raises the paired PSNR of 4 held-out scenes. Skipped
when the shared real-pairs folder is absent."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from camdegrade import load_profile
from camdegrade.effects import Sharpen
from camdegrade.effects.base import evenly_spaced
from conftest import PAPER_BUILT_IN, load_script

pytestmark = [pytest.mark.realdata, pytest.mark.slow]
torch.set_num_threads(1)


def _psnr(sims: list[torch.Tensor], reals: list[torch.Tensor]) -> float:
    errors = [float((sim.double() - real.double()).pow(2).mean()) for sim, real in zip(sims, reals, strict=True)]
    return sum(-10 * math.log10(error) for error in errors) / len(errors)


def test_the_iphone_sharpens_beyond_the_built_in(real_pairs_dir: Path) -> None:
    example = load_script("experiments/sharpen_city100.py", "camdegrade_sharpen_city100")
    profile = load_profile(PAPER_BUILT_IN)
    cleans, reals = example.load(real_pairs_dir, evenly_spaced(example.FIT, 8))
    sources = profile.simulate(cleans, seed=0, deterministic=True)
    fitted = Sharpen.fit(sources, reals, **Sharpen.fit_options(sources))
    assert 0.1 < float(fitted.amount) < 0.5 and float(fitted.sigma) > 2.0, fitted
    cleans, reals = example.load(real_pairs_dir, example.HELD_OUT[::4])
    built_in = profile.simulate(cleans, seed=0, deterministic=True)
    with torch.no_grad():
        sharpened = [fitted(image[None])[0] for image in built_in]
    assert _psnr(sharpened, reals) > _psnr(built_in, reals) + 0.3
