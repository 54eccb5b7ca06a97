"""camdegrade: make clean training images look as if one specific camera had captured them.

Public API::

    from camdegrade import CameraDegrade, CameraProfile, load_profile, list_profiles
    from camdegrade import DegradedDataset, BatchDegrade, VirtualCamera, fit_profile
    from camdegrade.diagnose import diagnose
"""

from camdegrade._version import __version__
from camdegrade.data import BatchDegrade, DegradedDataset, DegradedIterableDataset, IndexedDataset
from camdegrade.errors import BatchError, CamdegradeError, ImageError, PairsError, ProfileError, UnknownProfileError
from camdegrade.fitting import fit_profile
from camdegrade.network import DomainShiftNet
from camdegrade.profile import CameraProfile, list_profiles, load_profile
from camdegrade.sim import VirtualCamera, simulate_pairs
from camdegrade.transform import CameraDegrade

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
    "PairsError",
    "ProfileError",
    "UnknownProfileError",
    "VirtualCamera",
    "__version__",
    "fit_profile",
    "list_profiles",
    "load_profile",
    "simulate_pairs",
]
