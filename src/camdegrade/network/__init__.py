"""The network of a profile: its architectures (:mod:`~camdegrade.network.nets`) and how they run at inference
(:mod:`~camdegrade.network.inference`: the precision choice and the CPU plans of their arithmetic)."""

# The package's face is nets.py's, name for name: its ``__all__`` is the one list of them.
from camdegrade.network.nets import *  # noqa: F403
from camdegrade.network.nets import __all__ as __all__
