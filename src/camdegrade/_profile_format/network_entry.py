"""The ``network`` entry of a profile's metadata, read without torch: which class it declares, its constructor
arguments (with what older files leave out filled in), the check its constructor would make, and the tensors it holds
(:mod:`camdegrade.network`'s classes import torch; tests keep the two in step)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from camdegrade._profile_format.effect_facts import short_repr
from camdegrade._support.recipes import UPSAMPLINGS
from camdegrade.errors import ProfileError

__all__ = [
    "CURVE_KNOTS",
    "DEFAULT_NETWORK_WIDTH",
    "FIELD_CHANNELS",
    "LEGACY_NETWORK_CONFIG",
    "LINEAR_TAPS",
    "MAX_NETWORK_WIDTH",
    "NETWORK_CLASSES",
    "check_network_config",
    "network_class",
    "network_config",
    "network_shapes",
    "network_shapes_of",
]

#: The widest network a profile may declare (``camdegrade.network.MAX_WIDTH``, which imports torch; a test keeps
#: the two equal) and the width of a network whose config names none.
MAX_NETWORK_WIDTH = 1024
DEFAULT_NETWORK_WIDTH = 64
#: The network classes a profile may declare in its ``network`` entry (``camdegrade.network``'s classes, which import
#: torch; a test keeps the two in step), each with the tensors it holds for a width.
NETWORK_CLASSES = ("DomainShiftNet", "LocalAffineNet")
#: Taps of ``LocalAffineNet``'s full-resolution filter and channels of its colour field (``camdegrade.network``).
LINEAR_TAPS, FIELD_CHANNELS, CURVE_KNOTS = 7, 12, 17


def network_class(spec: Any, path: Path) -> str:
    """The class name a (non-null) ``network`` metadata entry declares, refused unless it is one of
    :data:`NETWORK_CLASSES`."""
    if not isinstance(spec, dict) or spec.get("arch") not in NETWORK_CLASSES:
        choices = " or ".join(repr(name) for name in NETWORK_CLASSES)
        raise ProfileError(
            f"profile {str(path)!r} metadata 'network' must be null or {{'arch': {choices}, 'config': ...}}, "
            f"got {short_repr(spec)}"
        )
    return spec["arch"]


#: Constructor arguments a profile may leave out because it was written before they existed, with the value such a
#: profile means: a ``LocalAffineNet`` without ``upsample`` was fitted with a bilinear colour field.
LEGACY_NETWORK_CONFIG = {"LocalAffineNet": {"upsample": "bilinear"}}


def network_config(spec: Any, path: Path) -> Any:
    """The constructor arguments of the network a (non-null) ``network`` metadata entry declares, with what older
    profiles leave out (:data:`LEGACY_NETWORK_CONFIG`) filled in."""
    legacy = LEGACY_NETWORK_CONFIG.get(network_class(spec, path), {})
    config = spec.get("config", {})
    return legacy | config if isinstance(config, dict) else config


def check_network_config(config: Any, arch: str = "DomainShiftNet") -> None:
    """Raise as the constructor of the network class ``arch`` would for a config it refuses (a test keeps the two in
    step)."""
    if not isinstance(config, dict):
        raise TypeError(f"the network config must be a mapping, got {type(config).__name__}")
    accepted = {"upsample", "curves"} if arch == "LocalAffineNet" else set()
    unexpected = sorted(set(config) - {"width", *accepted})
    if unexpected:
        raise TypeError(f"unexpected network config keys {short_repr(unexpected)}")
    width = config.get("width", DEFAULT_NETWORK_WIDTH)
    if isinstance(width, bool) or not isinstance(width, int) or not 1 <= width <= MAX_NETWORK_WIDTH:
        raise ValueError(f"width must be an integer from 1 to {MAX_NETWORK_WIDTH}, got width={short_repr(width)}")
    upsample = config.get("upsample", UPSAMPLINGS[0])
    if upsample not in UPSAMPLINGS:
        raise ValueError(f"upsample must be one of {UPSAMPLINGS}, got upsample={short_repr(upsample)}")
    curves = config.get("curves", False)
    if not isinstance(curves, bool):
        raise ValueError(f"curves must be True or False, got curves={short_repr(curves)}")


def network_shapes(width: int, arch: str = "DomainShiftNet", curves: bool = False) -> dict[str, tuple[int, ...]]:
    """The tensors of the network class ``arch`` at ``width`` in a profile (a test compares them with the module's)."""
    double = 2 * width
    shapes = {
        "network.encode1.weight": (width, 3, 3, 3),
        "network.encode1.bias": (width,),
        "network.encode2.weight": (double, width, 3, 3),
        "network.encode2.bias": (double,),
    }
    if arch == "LocalAffineNet":
        return (
            shapes
            | {
                "network.linear.weight": (3, 3, LINEAR_TAPS, LINEAR_TAPS),
                "network.linear.bias": (3,),
                "network.decode1.weight": (width, double, 1, 1),
                "network.decode1.bias": (width,),
                "network.decode2.weight": (FIELD_CHANNELS, width, 1, 1),
                "network.decode2.bias": (FIELD_CHANNELS,),
            }
            | ({"network.curve": (2, 3, CURVE_KNOTS)} if curves else {})
        )
    return shapes | {
        "network.decode1.weight": (double, width, 2, 2),
        "network.decode1.bias": (width,),
        "network.decode2.weight": (width, 3, 2, 2),
        "network.decode2.bias": (3,),
    }


def network_shapes_of(spec: Any, path: Path) -> dict[str, tuple[int, ...]]:
    """The network tensors the metadata's ``network`` entry ``spec`` declares (none for ``null``)."""
    if spec is None:
        return {}
    config = network_config(spec, path)
    try:
        check_network_config(config, spec["arch"])
    except (TypeError, ValueError) as error:
        raise ProfileError(f"profile {str(path)!r} has invalid metadata: {error}") from None
    return network_shapes(config.get("width", DEFAULT_NETWORK_WIDTH), spec["arch"], config.get("curves", False))
