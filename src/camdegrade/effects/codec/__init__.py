"""Effects of the codec stage (``stage = "codec"``): JPEG through libjpeg, and the learned texture that comes last."""

__all__: list[str] = []
