"""Sim-to-real gap diagnosis: where simulated images still differ from real captures, which camera effect the
profile does not model, and how much of the gap closes once it is added (``docs/diagnosis.md``)."""

from camdegrade.diagnose.core import diagnose
from camdegrade.diagnose.report import DiagnosisReport

__all__ = ["DiagnosisReport", "diagnose"]
