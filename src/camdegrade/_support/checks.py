"""Checks of user arguments, each raising an error that names the argument, the rule and the value received."""

from __future__ import annotations

import math
from typing import Any

#: The seeds ``torch.Generator.manual_seed`` accepts.
SEED_RANGE = (-(2**63), 2**64 - 1)


def check_int(name: str, value: Any, minimum: int | None = None, maximum: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"{name} must be an int, got {name}={value!r} ({type(value).__name__})")
    if minimum is not None and value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {name}={value}")
    if maximum is not None and value > maximum:
        raise ValueError(f"{name} must be an integer <= {maximum}, got {name}={value}")
    return value


def check_seed(value: Any, name: str = "seed") -> int:
    """An integer seed torch can use (from −2**63 to 2**64 − 1)."""
    check_int(name, value)
    low, high = SEED_RANGE
    if not low <= value <= high:
        raise ValueError(f"{name} must be an integer from -2**63 to 2**64 - 1, got {name}={value}")
    return value


def check_probability(p: Any, name: str = "p") -> float:
    if isinstance(p, bool) or not isinstance(p, (int, float)) or not 0.0 <= p <= 1.0:
        raise ValueError(f"{name} must be a probability from 0 to 1, got {name}={p!r}")
    return float(p)


def check_non_negative(value: Any, name: str) -> float:
    """A finite number >= 0 (anything ``float()`` takes but a bool), as a float."""
    try:
        number = float(value) if not isinstance(value, bool) else math.nan
    except (TypeError, ValueError):
        number = math.nan
    if not (math.isfinite(number) and number >= 0):
        raise ValueError(f"{name} must be a finite non-negative number, got {name}={value!r}")
    return number
