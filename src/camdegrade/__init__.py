"""camdegrade: make clean training images look as if one specific camera had captured them.

Public API::

    from camdegrade import CameraDegrade, CameraProfile, load_profile, list_profiles
"""

from camdegrade._version import __version__
from camdegrade.errors import CamdegradeError, PairsError, ProfileError, UnknownProfileError
from camdegrade.network import DomainShiftNet
from camdegrade.profile import CameraProfile, list_profiles, load_profile
from camdegrade.transform import CameraDegrade

__all__ = [
    "CamdegradeError",
    "CameraDegrade",
    "CameraProfile",
    "DomainShiftNet",
    "PairsError",
    "ProfileError",
    "UnknownProfileError",
    "__version__",
    "list_profiles",
    "load_profile",
]
