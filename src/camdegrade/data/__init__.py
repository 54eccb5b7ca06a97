"""Training on clean and camera-degraded images together (Hegde et al.'s recipe), reproducibly.

- :class:`DegradedDataset` / :class:`DegradedIterableDataset` wrap a dataset and degrade the items a mixing
  policy picks (:class:`Union`, :class:`PairedViews`, :class:`Bernoulli`, :class:`Alternate`, :class:`Ratio`,
  :class:`Schedule`), identically for any number of workers or ranks.
- :class:`BatchDegrade` degrades a collated batch on its device with the same decisions and values.

See ``docs/data.md``.
"""

from camdegrade.data._keys import item_generator, item_uniform, stable_key
from camdegrade.data.batch import BatchDegrade
from camdegrade.data.datasets import DegradedDataset, DegradedIterableDataset, IndexedDataset, as_camera_degrade
from camdegrade.data.policies import (
    Alternate,
    Bernoulli,
    MixPolicy,
    PairedViews,
    Ratio,
    Schedule,
    Union,
    resolve_policy,
)

__all__ = [
    "Alternate",
    "BatchDegrade",
    "Bernoulli",
    "DegradedDataset",
    "DegradedIterableDataset",
    "IndexedDataset",
    "MixPolicy",
    "PairedViews",
    "Ratio",
    "Schedule",
    "Union",
    "as_camera_degrade",
    "item_generator",
    "item_uniform",
    "resolve_policy",
    "stable_key",
]
