"""camdegrade: make clean training images look as if one specific camera had captured them.

Public API::

    from camdegrade import CameraDegrade, CameraProfile, load_profile, list_profiles
    from camdegrade import DegradedDataset, BatchDegrade, VirtualCamera, fit_profile
    from camdegrade.diagnose import diagnose

``import camdegrade`` imports neither torch nor torchvision (which take seconds): each public name is imported from
its module when it is first used (PEP 562), so ``camdegrade --help``, ``list`` and ``info`` answer at once. The
errors, ``__version__`` and ``list_profiles`` need no torch at all. Subpackages and modules (``camdegrade.profile``,
...) are imported on first attribute access too.
"""

from __future__ import annotations

import importlib
import importlib.util
from typing import TYPE_CHECKING, Any

from camdegrade._profile_format.header import list_profiles
from camdegrade._version import __version__
from camdegrade.errors import (
    BatchError,
    CamdegradeError,
    ImageError,
    PairsError,
    PlainTensorsWarning,
    ProfileError,
    ProfileTypeError,
    UnknownProfileError,
)

if TYPE_CHECKING:  # what type checkers and IDEs see; at run time, __getattr__ imports these on first use
    from camdegrade.data import BatchDegrade, DegradedDataset, DegradedIterableDataset, IndexedDataset
    from camdegrade.fitting import fit_profile
    from camdegrade.network import DomainShiftNet, LocalAffineNet
    from camdegrade.profile import CameraProfile, load_profile
    from camdegrade.sim import VirtualCamera, simulate_pairs
    from camdegrade.transform import CameraDegrade

#: Public name → the module it is imported from on first use (each of these modules imports torch).
_LAZY: dict[str, str] = {
    "BatchDegrade": "camdegrade.data",
    "DegradedDataset": "camdegrade.data",
    "DegradedIterableDataset": "camdegrade.data",
    "IndexedDataset": "camdegrade.data",
    "fit_profile": "camdegrade.fitting",
    "DomainShiftNet": "camdegrade.network",
    "LocalAffineNet": "camdegrade.network",
    "CameraProfile": "camdegrade.profile",
    "load_profile": "camdegrade.profile",
    "VirtualCamera": "camdegrade.sim",
    "simulate_pairs": "camdegrade.sim",
    "CameraDegrade": "camdegrade.transform",
}

__all__ = [
    "BatchDegrade",
    "BatchError",
    "CamdegradeError",
    "CameraDegrade",
    "CameraProfile",
    "DegradedDataset",
    "DegradedIterableDataset",
    "DomainShiftNet",
    "ImageError",
    "IndexedDataset",
    "LocalAffineNet",
    "PairsError",
    "PlainTensorsWarning",
    "ProfileError",
    "ProfileTypeError",
    "UnknownProfileError",
    "VirtualCamera",
    "__version__",
    "fit_profile",
    "list_profiles",
    "load_profile",
    "simulate_pairs",
]


def __getattr__(name: str) -> Any:
    """A public name imported from its module on first use, or a submodule (``camdegrade.profile``)."""
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
    elif not name.startswith("__") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        value = importlib.import_module(f"{__name__}.{name}")
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value  # later uses find it without this function
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
