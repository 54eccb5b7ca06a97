"""Shared fixtures."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

_REAL_PAIRS_ENV = "CAMDEGRADE_REAL_PAIRS"

# albumentations asks PyPI for a newer version when first imported (and warns when offline); tests download nothing.
# Set here, before collection, because the doctests under src/ import camdegrade.integrations.albumentations too.
os.environ.setdefault("NO_ALBUMENTATIONS_UPDATE", "1")


@pytest.fixture(scope="session")
def real_pairs_dir() -> Path:
    """The shared folder of real (clean, captured) pairs holding ``pairs.csv``; the test is skipped when absent.

    Defaults to ``<repo>/../shared/data/real-pairs``; set ``CAMDEGRADE_REAL_PAIRS`` to use another copy.
    """
    default = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real-pairs"
    folder = Path(os.environ.get(_REAL_PAIRS_ENV) or default)
    if not (folder / "pairs.csv").is_file():
        pytest.skip(f"real pairs not found at {folder} (set {_REAL_PAIRS_ENV} to their folder)")
    return folder
