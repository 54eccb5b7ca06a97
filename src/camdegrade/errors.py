"""Exceptions raised by camdegrade. Each names the argument, what was expected and what was received."""

from __future__ import annotations


class CamdegradeError(Exception):
    """Base class of every error camdegrade raises on purpose."""


class ProfileError(CamdegradeError, ValueError):
    """A profile file or profile name could not be used."""


class UnknownProfileError(ProfileError, KeyError):
    """A profile name is neither a built-in profile nor an existing file."""

    def __str__(self) -> str:  # KeyError would otherwise quote the message
        return str(self.args[0]) if self.args else ""


class UnknownPresetError(CamdegradeError, KeyError):
    """A virtual camera preset name is not one of the known presets."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


class PairsError(CamdegradeError, ValueError):
    """A set of (clean, captured) pairs could not be used."""
