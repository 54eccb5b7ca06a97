"""The network of a paired fit: its training (:func:`~camdegrade.fitting.network.training.fit_network`, with the
recipe's values), checkpoints, the least-squares linear baseline it starts from and is judged against, a short
fine-tune (diagnosis's network refit), and distillation into a narrower network."""

__all__ = []
