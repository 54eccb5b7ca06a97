"""Traces a camera's processing leaves in its images: JPEG's quantisation lattice (:mod:`.quantisation`) and a
digital upscale's spectral coherence (:mod:`.resampling`)."""

__all__: list[str] = []
