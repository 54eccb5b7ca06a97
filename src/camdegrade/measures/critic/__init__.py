"""The learned critic: can a small CNN tell real captures from simulated ones (:mod:`.core`), and why it decides
as it does (:mod:`.explain`)."""

__all__: list[str] = []
