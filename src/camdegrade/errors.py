"""Exceptions raised by camdegrade. Each names the argument, what was expected and what was received."""

from __future__ import annotations

__all__ = [
    "BatchError",
    "CamdegradeError",
    "CheckpointError",
    "FitInterrupted",
    "ImageError",
    "PairsError",
    "PlainTensorsWarning",
    "ProfileError",
    "ProfileTypeError",
    "UnknownPresetError",
    "UnknownProfileError",
]


class CamdegradeError(Exception):
    """Base class of every error camdegrade raises on purpose."""


class FitInterrupted(CamdegradeError):
    """A fit was interrupted (Ctrl-C); the checkpoint of its last finished epoch (or step) is kept for ``resume``.
    Here rather than with the network's training: the learned texture stage's trainer raises it too."""


class CheckpointError(CamdegradeError, ValueError):
    """A checkpoint cannot be resumed from: not a checkpoint of this fit, damaged, or written for other images or
    options."""


class ProfileError(CamdegradeError, ValueError):
    """A profile file or profile name could not be used."""


class ProfileTypeError(ProfileError, TypeError):
    """A profile's metadata holds a value of the wrong JSON type (a string where a boolean belongs, say)."""


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


class ImageError(CamdegradeError, OSError):
    """An image file could not be used: unreadable, truncated, animated, or larger than camdegrade decodes."""


class BatchError(CamdegradeError):
    """Some files of a batch could not be processed; every other file was. ``failed`` holds ``(path, reason)``
    for each failure and ``done`` what was written."""

    def __init__(self, message: str, failed: list[tuple[object, str]], done: list[object]) -> None:
        super().__init__(message)
        self.failed = failed
        self.done = done


class PlainTensorsWarning(UserWarning):
    """A sample holds several plain image-shaped tensors and no explicit image: only the first is degraded
    (torchvision's rule); wrap images in ``tv_tensors.Image`` to degrade them all."""
