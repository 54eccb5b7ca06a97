"""Measurement kernels on images: luma, windows, local means, flat-pixel masks (:mod:`.images`), and the noise
structure where the clean image is flat (:mod:`.noise`)."""

__all__: list[str] = []
