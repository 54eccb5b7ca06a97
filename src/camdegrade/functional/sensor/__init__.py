"""Kernels of the sensor stage: Poisson–Gaussian noise (:mod:`.noise`) and a sensor of fewer pixels
(:mod:`.resolution`)."""

__all__: list[str] = []
