"""Kernels of the optics stage: the point-spread function (:mod:`.blur`) and the position-dependent ones
(:mod:`.geometry`)."""

__all__: list[str] = []
