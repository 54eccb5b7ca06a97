"""Effects of the ISP stage (``stage = "isp"``): colour and tone, resolution, sharpening, noise reduction and the
frequency response, with the detail stages' shared loss."""

__all__: list[str] = []
