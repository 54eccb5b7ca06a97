"""The registered statistic families, one module each (imported by :mod:`camdegrade.measures` in the order of
every report): spatial, intensity, noise, frequency, blocks, color, alignment, and the no-reference families."""

__all__: list[str] = []
