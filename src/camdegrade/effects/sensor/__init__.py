"""Effects of the sensor stage (``stage = "sensor"``): camera noise and its estimator."""

__all__: list[str] = []
