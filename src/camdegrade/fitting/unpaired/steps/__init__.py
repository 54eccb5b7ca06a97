"""The unpaired fit's stage steps: each proposes a stage from set statistics of the captures and the clean images
(or the profile's simulation of them) and is judged on split halves (:mod:`camdegrade.fitting.unpaired.judges`)."""

__all__: list[str] = []
