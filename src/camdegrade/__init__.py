"""camdegrade: make clean training images look as if one specific camera had captured them.

Public API::

    from camdegrade import CameraDegrade, CameraProfile, load_profile, list_profiles, profile_summary
    from camdegrade import DegradedDataset, BatchDegrade, VirtualCamera
    from camdegrade import PairSet, FitConfig, fit_profile, fit_unpaired, distill_profile, diagnose

``camdegrade.diagnose`` is both the subpackage (``camdegrade.diagnose.DiagnosisReport``) and, called, its
``diagnose`` function (``camdegrade.diagnose(profile, pairs)``), whichever of the two is imported first.

``import camdegrade`` imports neither torch nor torchvision (which take seconds): each public name is imported from
its module when it is first used (PEP 562), so ``camdegrade --help``, ``list`` and ``info`` answer at once. The
errors, ``__version__``, ``list_profiles`` and ``profile_summary`` need no torch at all. Subpackages and modules
(``camdegrade.profile``, ...) are imported on first attribute access too.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import types
from typing import TYPE_CHECKING, Any

from camdegrade._profile_format.header import list_profiles
from camdegrade._profile_format.summary import profile_summary
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
    from camdegrade.diagnose import diagnose
    from camdegrade.fitting import FitConfig, PairSet, distill_profile, fit_profile
    from camdegrade.fitting.unpaired import fit_unpaired
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
    "FitConfig": "camdegrade.fitting",
    "PairSet": "camdegrade.fitting",
    "distill_profile": "camdegrade.fitting",
    "fit_profile": "camdegrade.fitting",
    "fit_unpaired": "camdegrade.fitting.unpaired",
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
    "FitConfig",
    "ImageError",
    "IndexedDataset",
    "LocalAffineNet",
    "PairSet",
    "PairsError",
    "PlainTensorsWarning",
    "ProfileError",
    "ProfileTypeError",
    "UnknownProfileError",
    "VirtualCamera",
    "__version__",
    "diagnose",
    "distill_profile",
    "fit_profile",
    "fit_unpaired",
    "list_profiles",
    "load_profile",
    "profile_summary",
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


class _DiagnosePackage(types.ModuleType):
    """The ``camdegrade.diagnose`` subpackage, callable as its own ``diagnose`` function."""

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self.diagnose(*args, **kwargs)

    @property
    def __signature__(self) -> Any:  # what inspect.signature and help() show: the function's
        import inspect

        return inspect.signature(self.diagnose)


class _Package(types.ModuleType):
    """``camdegrade`` itself. Importing a subpackage sets it as an attribute of its parent, so the name
    ``camdegrade.diagnose`` is always the subpackage; made callable here, it is also the top-level function."""

    def __setattr__(self, name: str, value: Any) -> None:
        if name == "diagnose" and type(value) is types.ModuleType:
            value.__class__ = _DiagnosePackage
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
