"""The unpaired fit: a camera profile from the camera's own photos and, optionally, clean images of other scenes
(:func:`fit_unpaired`), the paired fit's loop of steps with split-half judges; and the statistics it matches, of any
profile (:func:`unpaired_fidelity`)."""

from camdegrade.fitting.unpaired.fit import (
    MIN_IMAGES,
    NOT_IDENTIFIABLE,
    UNPAIRED_EFFECTS,
    UNPAIRED_STEPS,
    fit_unpaired,
    unpaired_fidelity,
)

__all__ = ["MIN_IMAGES", "NOT_IDENTIFIABLE", "UNPAIRED_EFFECTS", "UNPAIRED_STEPS", "fit_unpaired", "unpaired_fidelity"]
