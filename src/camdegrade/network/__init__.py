"""The network of a profile: its architectures (:mod:`~camdegrade.network.nets`) and how they run at inference
(:mod:`~camdegrade.network.inference`: the precision choice and the CPU plans of their arithmetic)."""

from camdegrade.network.nets import (
    ARCHITECTURES,
    CURVE_KNOTS,
    FIELD_CHANNELS,
    FIELD_SMOOTHING,
    FIELD_UPSAMPLING,
    LINEAR_TAPS,
    MAX_WIDTH,
    SIZE_MULTIPLE,
    DomainShiftNet,
    LocalAffineNet,
    ShiftNetwork,
    build_network,
    check_batch,
    piecewise_linear,
    smoothed,
)

__all__ = [
    "ARCHITECTURES",
    "CURVE_KNOTS",
    "FIELD_CHANNELS",
    "FIELD_SMOOTHING",
    "FIELD_UPSAMPLING",
    "LINEAR_TAPS",
    "MAX_WIDTH",
    "SIZE_MULTIPLE",
    "DomainShiftNet",
    "LocalAffineNet",
    "ShiftNetwork",
    "build_network",
    "check_batch",
    "piecewise_linear",
    "smoothed",
]
