"""Shared fixtures."""

from __future__ import annotations

import importlib.util
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from types import ModuleType

import pytest

_REAL_PAIRS_ENV = "CAMDEGRADE_REAL_PAIRS"
REPOSITORY = Path(__file__).resolve().parents[1]
#: The built-in city100-iphonex as shipped until 2026-11-27: the paper's network (DomainShiftNet, width 64) with blur,
#: noise and tone stages. Tests of the paper network's CPU plan, of its 4-pixel grid and of the file checks on that
#: stage layout read it; the built-in itself is now a local-affine fit.
PAPER_BUILT_IN = REPOSITORY / "tests" / "fixtures" / "city100-iphonex-paper.safetensors"

# albumentations asks PyPI for a newer version when first imported (and warns when offline); tests download nothing.
# Set here, before collection, because the doctests under src/ import camdegrade.integrations.albumentations too.
os.environ.setdefault("NO_ALBUMENTATIONS_UPDATE", "1")


def pytest_configure(config: pytest.Config) -> None:
    """Under pytest-xdist (``make test`` runs one worker per core) each worker gets its share of the cores, so that
    two workers of two torch threads each do not fight over two cores."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if workers > 1:
        import torch

        torch.set_num_threads(max(1, (os.cpu_count() or 1) // workers))


@pytest.fixture(scope="session", autouse=True)
def _no_unpaired_critic() -> Iterator[int]:
    """The unpaired fit's self-check critic (two critics trained: seconds a fit) is measured only by the tests that
    ask for it (the :func:`unpaired_critic` fixture); every other unpaired fit of the suite records it as not
    measured, so that a hundred small fits do not spend minutes on a number their tests do not read. Yields the
    package's own minimum."""
    from camdegrade.fitting.unpaired import judges

    with pytest.MonkeyPatch.context() as patch:
        default = judges.MIN_CRITIC_IMAGES
        patch.setattr(judges, "MIN_CRITIC_IMAGES", sys.maxsize)
        yield default


@pytest.fixture
def unpaired_critic(_no_unpaired_critic: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """The unpaired fits of this test measure the self-check critic, as a user's fit does."""
    from camdegrade.fitting.unpaired import judges

    monkeypatch.setattr(judges, "MIN_CRITIC_IMAGES", _no_unpaired_critic)


#: Why the suite's unpaired fits leave the learned texture stage out (see :func:`_no_learned_texture`).
NO_LEARNED_TEXTURE = "not fitted in the test suite (the learned_texture fixture fits it)"


@pytest.fixture(scope="session", autouse=True)
def _no_learned_texture() -> Iterator[Callable[..., str | None]]:
    """The unpaired fit's learned texture step (three trainings of 1,200 steps and their critics: minutes a fit) is
    run only by the tests that ask for it (the :func:`learned_texture` fixture); every other unpaired fit of the
    suite records it as not fitted, with :data:`NO_LEARNED_TEXTURE`, as a fit of too few images does. Yields the
    package's own rule."""
    from camdegrade.fitting.two_sample import step

    with pytest.MonkeyPatch.context() as patch:
        default = step.too_few_patches
        patch.setattr(step, "too_few_patches", lambda *args, **options: NO_LEARNED_TEXTURE)
        yield default


@pytest.fixture
def learned_texture(_no_learned_texture: Callable[..., str | None], monkeypatch: pytest.MonkeyPatch) -> None:
    """The unpaired fits of this test run the learned texture step where their images are enough, as a user's fit
    does."""
    from camdegrade.fitting.two_sample import step

    monkeypatch.setattr(step, "too_few_patches", _no_learned_texture)


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


def load_script(relative_path: str, module_name: str) -> ModuleType:
    """A script of the repository (``examples/...``, ``experiments/...``, ``bench/...``: not a package) imported as
    ``module_name``.

    Tests import it as ``from conftest import load_script``. The module is put in ``sys.modules`` before it runs,
    because dataclasses and pickling look a class's module up by name. While it runs, its folder is first on
    ``sys.path``, as when Python runs the script, so that it imports its sibling modules (``bench/residual_cnn.py``).
    """
    path = REPOSITORY / relative_path
    spec = importlib.util.spec_from_file_location(module_name, path)
    assert spec is not None and spec.loader is not None, relative_path
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module
    sys.path.insert(0, str(path.parent))
    try:
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(path.parent))
    return module
