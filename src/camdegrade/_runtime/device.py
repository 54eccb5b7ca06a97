"""The one check of a torch device argument (the library's ``device=`` and the command line's ``--device``)."""

from __future__ import annotations

from typing import Any


def check_device(device: Any, name: str = "device") -> Any:
    """``device`` as a ``torch.device`` after checking that a tensor can live on it here; else a ``ValueError``
    naming ``name`` (``"--device"`` on the command line), the device and why (not a device, no CUDA, ``meta``, a
    backend not built in)."""
    import torch

    try:
        parsed = torch.device(device)
    except (RuntimeError, ValueError, TypeError):
        raise ValueError(
            f"{name} must be a torch device usable here, got {name}={device!r} (e.g. 'cpu' or 'cuda:0')"
        ) from None
    if parsed.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"{name} {str(device)!r} asks for CUDA, but no CUDA device is available here")
    if parsed.type == "meta":
        raise ValueError(f"{name} 'meta' holds no data, so nothing can be computed on it; use 'cpu' or 'cuda'")
    try:
        torch.empty(1, device=parsed)
    except Exception as error:  # a backend that is not built in may raise anything (ImportError, ...)
        reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise ValueError(f"{name} {str(device)!r} cannot be used here ({reason})") from None
    return parsed
