"""Adapters for training stacks camdegrade does not depend on. Import the one you use; each needs its own extra.

- :mod:`camdegrade.integrations.albumentations`: :class:`AlbumentationsCameraDegrade`, a camera profile as an
  albumentations transform (numpy HWC in and out); ``pip install 'camdegrade[albumentations]'``.

Hugging Face ``datasets`` and Lightning need no adapter: :class:`camdegrade.DegradedDataset` wraps a ``datasets``
dataset as it is, and ``examples/lightning_datamodule.py`` wires ``set_epoch`` to the trainer. See
``docs/integrations.md``.

This package imports nothing itself, so ``import camdegrade`` never imports albumentations, datasets or Lightning.
"""

__all__: list[str] = []  # the adapters are imported by module: camdegrade.integrations.albumentations
