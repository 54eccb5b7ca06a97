"""A profile's recorded quality as a few lines for people (``camdegrade fit`` at the end, ``camdegrade info``):
PSNR of the identity, the linear baseline, the network and the profile, then its fidelity (grid, bands, flat noise,
the critic with and without the clean source). Reads the metadata only: no torch."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


def quality_lines(quality: Mapping[str, Any]) -> list[str]:
    """The lines for ``quality`` (a profile's ``quality`` metadata); none when it records no PSNR."""
    psnr = [
        f"{label} {_db(quality[key])}"
        for label, key in (
            ("identity", "identity_psnr_db"),
            ("baseline", "baseline_psnr_db"),
            ("network", "network_psnr_db"),
            ("profile", "profile_psnr_db"),
        )
        if key in quality
    ]
    if not psnr:
        return []
    where = _pairs(quality)
    lines = [f"{where} PSNR: {', '.join(psnr)}"]
    fidelity = quality.get("fidelity")
    if isinstance(fidelity, Mapping):
        lines.append(f"{where} fidelity (simulation vs capture, 1 or 0: the same): {_fidelity(fidelity)}")
        lines.append(f"{where} critic (0.5: cannot tell them apart): {_critics(fidelity)}")
    return lines


def _pairs(quality: Mapping[str, Any]) -> str:
    for key, label in (("validation_pairs", "validation"), ("held_out_pairs", "held-out")):
        if _is_number(quality.get(key)):
            return f"{label} ({_number(quality[key], 0)} pairs)"
    return "quality"


def _db(value: Any) -> str:
    return "inf dB (identical)" if value is None else f"{_number(value)} dB"


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _number(value: Any, digits: int = 2) -> str:
    """A number as text; anything else in the metadata (it comes from a file) as ``n/a``, never as itself."""
    return f"{value:.{digits}f}" if _is_number(value) else "n/a"


def _fidelity(fidelity: Mapping[str, Any]) -> str:
    bands = fidelity.get("bands")
    shown = " ".join(_signed(value) for value in bands) if isinstance(bands, list) else "n/a"
    return (
        f"grid ratio {_number(fidelity.get('grid_ratio'))}, bands log2 {shown}, noise ratio "
        f"{_number(fidelity.get('noise_ratio'))}, banding ratio {_number(fidelity.get('banding_ratio'))}"
    )


def _signed(value: Any) -> str:
    return f"{value:+.2f}" if _is_number(value) else "n/a"


def _critics(fidelity: Mapping[str, Any]) -> str:
    parts = []
    for label, key in (("paired", "critic_paired"), ("image-only", "critic_image_only")):
        result = fidelity.get(key)
        if isinstance(result, Mapping):
            parts.append(
                f"{label} {_number(result.get('accuracy'))}{_spread(result)} [95 % CI {_number(result.get('low'))}-"
                f"{_number(result.get('high'))}, {_number(result.get('pairs'), 0)} held-out pairs]"
            )
        else:
            parts.append(f"{label} not run")
    return ", ".join(parts)


def _spread(result: Mapping[str, Any]) -> str:
    """`` ± std over N critics`` where several critics were trained (profiles before them hold one)."""
    critics = result.get("critics")
    if not _is_number(critics) or critics < 2:
        return ""
    return f" ± {_number(result.get('std'))} over {_number(critics, 0)} critics"
