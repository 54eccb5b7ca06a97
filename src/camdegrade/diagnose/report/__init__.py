"""The diagnosis report: its record, JSON and one self-contained HTML page (:mod:`.document`), the evidence plots
(:mod:`.plots`), the crops for people (:mod:`.crops`) and the critic's section (:mod:`.critic_html`)."""

from camdegrade.diagnose.report.document import REQUIRED_KEYS, DiagnosisReport, render_html

__all__ = ["REQUIRED_KEYS", "DiagnosisReport", "render_html"]
