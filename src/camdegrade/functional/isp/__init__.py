"""Kernels of the ISP stage: colour in linear light (:mod:`.color`), the tone curve (:mod:`.tone`), sharpening and
coring (:mod:`.sharpen`), the luma frequency response (:mod:`.response`)."""

__all__: list[str] = []
