"""The warning a paired fit gives where the captures show a block codec the profile cannot hold: JPEG at the
sensor's resolution before the camera's upscale, read from the fit's jpeg record
(:func:`camdegrade.fitting.jpeg_evidence.sensor_grid_note`: the block edges at the sensor's period, in the captures
and simulated). A ``jpeg`` stage sits last and compresses the full frame; ``resolution`` reduces and enlarges in one
stage, so nothing can compress between the two."""

from __future__ import annotations

from typing import Any

__all__ = ["SENSOR_GRID_EXCESS", "codec_warnings"]

#: A fit warns where the captures' block-edge ratio at the sensor's period exceeds the simulation's by this much
#: (relative gradient energy; the foreign webcam, without a codec, read 0.01 above; JPEG 70 before a 2x zoom 0.20;
#: the lowcost-robot preset, JPEG 45 at half size, 0.99: docs/results.md, *JPEG among the default fit's stages*).
SENSOR_GRID_EXCESS = 0.1


def codec_warnings(records: dict[str, Any]) -> list[str]:
    """The fit's warning (a list of at most one) where its jpeg record (``records['effects']['jpeg']``) found block
    edges at the sensor's period that the simulation lacks by :data:`SENSOR_GRID_EXCESS`: a codec before the
    camera's upscale, which the profile cannot hold."""
    note = (records.get("effects") or {}).get("jpeg") or {}
    real, sim = note.get("sensor_grid_real"), note.get("sensor_grid_sim")
    if real is None or sim is None or real - sim < SENSOR_GRID_EXCESS:
        return []
    return [
        f"the captures' gradient energy across block edges at the sensor's {note['sensor_period']} px period is "
        f"{real:.2f}× the mean against {sim:.2f}× simulated: a block codec (JPEG) at the sensor's resolution before "
        "the camera's upscale, which the profile cannot hold (a jpeg stage compresses the full frame): its blocks "
        "are missing from the simulation"
    ]
