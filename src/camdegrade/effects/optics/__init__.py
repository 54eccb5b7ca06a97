"""Effects of the optics stage (``stage = "optics"``): blur, and the position-dependent vignetting, distortion,
chromatic aberration and misalignment, with their warp fitter."""

__all__: list[str] = []
