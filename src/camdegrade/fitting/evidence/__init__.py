"""Fit steps for stages that leave a trace of their own in the captures, proposed only where the captures show it and
the clean images do not, and kept only where the simulation comes to show it as the captures do: the colour filter
array (:mod:`camdegrade.fitting.evidence.cfa`). (The JPEG stage's step, :mod:`camdegrade.fitting.jpeg_evidence`, is
the first of the kind.)"""

from camdegrade.fitting.evidence.cfa import CfaStage

__all__ = ["CfaStage"]
