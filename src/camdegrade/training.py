"""Deprecated: moved to :mod:`camdegrade.fitting.training` (the fitting flow lives in ``camdegrade.fitting``)."""

from camdegrade._deprecated import moved_module

__getattr__ = moved_module(__name__, "camdegrade.fitting.training")
