"""Where and how a call runs: the device argument, the ``torch.distributed`` rank, torch's CPU threads, and the
bounded cache of a profile's simulations."""

__all__: list[str] = []
