"""Dataset wrappers that mix clean and camera-degraded samples: map-style, iterable, and an index-returning one."""

from __future__ import annotations

import operator
import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any

import torch
from torch.utils.data import Dataset, IterableDataset, get_worker_info

from camdegrade._runtime.distributed import rank_and_world_size
from camdegrade._support.checks import check_seed
from camdegrade.data._keys import SharedEpoch, item_generator
from camdegrade.data.policies import Decision, MixPolicy, resolve_policy
from camdegrade.profile import CameraProfile
from camdegrade.transform import CameraDegrade

__all__ = [
    "DegradeLike",
    "DegradedDataset",
    "DegradedIterableDataset",
    "IndexedDataset",
    "as_camera_degrade",
    "resolve_seed",
]

#: What a ``degrade`` argument may be: the transform itself, a profile, a built-in profile name or a profile path.
DegradeLike = CameraDegrade | CameraProfile | str | os.PathLike


def as_camera_degrade(degrade: DegradeLike) -> CameraDegrade:
    """``degrade`` as a :class:`CameraDegrade` (profiles, names and paths are wrapped; its ``p`` is not used here)."""
    if isinstance(degrade, CameraDegrade):
        return degrade
    if isinstance(degrade, (CameraProfile, str, os.PathLike)):
        return CameraDegrade(degrade)
    raise TypeError(
        "degrade must be a CameraDegrade, a CameraProfile, a built-in profile name or a profile path, "
        f"got {type(degrade).__name__}"
    )


def resolve_seed(seed: int | None) -> int:
    """``seed`` itself, or (for ``None``) one drawn once from torch's global RNG, so ``torch.manual_seed`` fixes it."""
    if seed is None:
        return int(torch.randint(0, 2**62, ()).item())
    return check_seed(seed)


class _Mixer:
    """What both wrappers share: the degradation, the policy, the seed, the epoch and the final transform."""

    def __init__(
        self, degrade: DegradeLike, policy: MixPolicy | str, seed: int | None, transform: Callable[[Any], Any] | None
    ) -> None:
        if transform is not None and not callable(transform):
            raise TypeError(f"transform must be callable or None, got {type(transform).__name__}")
        self.degrade = as_camera_degrade(degrade)
        self.policy = resolve_policy(policy)
        self.seed = resolve_seed(seed)
        self.transform = transform
        self._epoch = SharedEpoch()

    @property
    def epoch(self) -> int:
        return self._epoch.get()

    def set_epoch(self, epoch: int) -> None:
        """Use ``epoch``'s decisions and degradations from now on, in this process and in running workers.

        Call it before iterating the DataLoader for that epoch (as with ``DistributedSampler.set_epoch``):
        items a worker has already prefetched keep the epoch they were loaded under.
        """
        self._epoch.set(epoch)

    def degrade_sample(self, sample: Any, index: int, epoch: int | None = None) -> Any:
        """``sample`` (source item ``index``) degraded exactly as this wrapper degrades it in ``epoch``."""
        epoch = self.epoch if epoch is None else epoch
        return self.degrade.degrade_with(sample, generator=item_generator(self.seed, epoch, index), p=1.0)

    def decision(self, index: int, copy: int = 0, epoch: int | None = None) -> Decision:
        """Whether copy ``copy`` of source item ``index`` is degraded in ``epoch`` (a tuple for paired policies)."""
        epoch = self.epoch if epoch is None else epoch
        return self.policy.decide(index, copy, epoch, self.seed)

    def _views(self, sample: Any, index: int, copy: int, epoch: int) -> Any:
        decision = self.policy.decide(index, copy, epoch, self.seed)
        if isinstance(decision, tuple):
            return tuple(self._view(sample, index, epoch, degraded) for degraded in decision)
        return self._view(sample, index, epoch, decision)

    def _view(self, sample: Any, index: int, epoch: int, degraded: bool) -> Any:
        view = self.degrade_sample(sample, index, epoch) if degraded else sample
        return view if self.transform is None else self.transform(view)

    def _describe(self, inner: Any) -> str:
        return (
            f"{type(self).__name__}(dataset={type(inner).__name__}, policy={self.policy!r}, seed={self.seed}, "
            f"epoch={self.epoch}, profile={self.degrade.profile.name!r})"
        )


class DegradedDataset(_Mixer, Dataset):
    """A map-style dataset returning some items as a camera would have captured them.

    The image(s) in each sample are found as :class:`~camdegrade.CameraDegrade` finds them (PIL images,
    ``tv_tensors.Image``/``Video``, or the first plain tensor), so ``(image, target)`` tuples, dicts and
    tv_tensors samples come back with the same structure; targets, boxes and masks are the same objects.

    Which items are degraded is the ``policy``'s answer for (source index, epoch, seed); how an item is degraded is
    drawn from a generator keyed on (seed, epoch, source index). Both are independent of worker, rank and loading
    order, so results are the same for any ``num_workers``, persistent workers, shuffling and
    ``DistributedSampler``. Call :meth:`set_epoch` each epoch for fresh decisions and noise.

    Args:
        dataset: any map-style dataset (``__getitem__`` and ``__len__``). Its transform should leave images as PIL,
            uint8, or float in ``[0, 1]``: normalise in ``transform`` instead.
        degrade: a :class:`~camdegrade.CameraDegrade` (its ``p`` and seed are not used), a
            :class:`~camdegrade.CameraProfile`, a built-in profile name or a profile path.
        policy: a :class:`MixPolicy` or ``"union"`` (default, the paper), ``"pair"``, ``"alternate"``.
        seed: seeds every decision and degradation; ``None`` draws one from torch's global RNG.
        transform: applied to every returned view after degradation (e.g. ``ToDtype`` + ``Normalize``).

    Examples:
        >>> from camdegrade import CameraProfile, DomainShiftNet
        >>> samples = [(torch.zeros(3, 8, 8, dtype=torch.uint8), label) for label in range(4)]
        >>> mixed = DegradedDataset(samples, CameraProfile(DomainShiftNet()), policy="union", seed=0)
        >>> image, label = mixed[1]  # wrapped index 1: source item 0, degraded; its label untouched
        >>> len(mixed), label, image.dtype
        (8, 0, torch.uint8)
    """

    def __init__(
        self,
        dataset: Sequence[Any] | Dataset,
        degrade: DegradeLike,
        policy: MixPolicy | str = "union",
        seed: int | None = None,
        transform: Callable[[Any], Any] | None = None,
    ) -> None:
        if isinstance(dataset, IterableDataset) or not (
            hasattr(dataset, "__getitem__") and hasattr(dataset, "__len__")
        ):
            raise TypeError(
                f"dataset must be map-style (__getitem__ and __len__), got {type(dataset).__name__}; "
                "wrap iterable datasets in DegradedIterableDataset"
            )
        self.dataset = dataset
        super().__init__(degrade, policy, seed, transform)

    def __len__(self) -> int:
        return self.policy.copies * len(self.dataset)

    def __getitem__(self, index: int) -> Any:
        index = operator.index(index)
        length = len(self)
        if not -length <= index < length:
            raise IndexError(f"index {index} is out of range for a DegradedDataset of length {length}")
        source, copy = divmod(index % length, self.policy.copies)
        return self._views(self.dataset[source], source, copy, self.epoch)

    def source_index(self, index: int) -> int:
        """The index in the wrapped dataset that item ``index`` of this one comes from."""
        return operator.index(index) // self.policy.copies

    def __getattr__(self, name: str) -> Any:
        # Delegate unknown attributes (classes, targets, ...) to the wrapped dataset, as timm's wrappers do.
        inner = self.__dict__.get("dataset")
        if inner is None or name.startswith("__"):
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        return getattr(inner, name)

    def __repr__(self) -> str:
        return self._describe(self.dataset)


class DegradedIterableDataset(_Mixer, IterableDataset):
    """:class:`DegradedDataset` for iterable datasets (streams): same policies, same sample handling.

    Streams have no index, so each sample gets one: ``index_of(sample)`` if given (a stable key such as a file
    number makes results independent of workers, ranks and sharding), otherwise its position in the stream the
    worker reads, as a round-robin global index ``(position * num_workers + worker_id) * world_size + rank``
    (reproducible for fixed ``num_workers``, ranks and sharding; distinct across workers and ranks).
    Each incoming sample yields ``policy.copies`` outputs in a row.

    Args:
        dataset: any iterable of samples (an ``IterableDataset``, a generator factory's result, a list...).
        index_of: optional ``sample -> int`` giving each sample its stable index.
        degrade, policy, seed, transform: as for :class:`DegradedDataset`.
    """

    def __init__(
        self,
        dataset: Iterable[Any],
        degrade: DegradeLike,
        policy: MixPolicy | str = "union",
        seed: int | None = None,
        transform: Callable[[Any], Any] | None = None,
        index_of: Callable[[Any], int] | None = None,
    ) -> None:
        if not isinstance(dataset, Iterable):
            raise TypeError(f"dataset must be iterable, got {type(dataset).__name__}")
        if index_of is not None and not callable(index_of):
            raise TypeError(f"index_of must be callable or None, got {type(index_of).__name__}")
        self.dataset = dataset
        self.index_of = index_of
        super().__init__(degrade, policy, seed, transform)

    def __iter__(self) -> Iterator[Any]:
        info = get_worker_info()
        workers, worker_id = (1, 0) if info is None else (info.num_workers, info.id)
        rank, world = rank_and_world_size()
        epoch = self.epoch
        for position, sample in enumerate(self.dataset):
            if self.index_of is None:
                index = (position * workers + worker_id) * world + rank
            else:
                index = operator.index(self.index_of(sample))
            for copy in range(self.policy.copies):
                yield self._views(sample, index, copy, epoch)

    def __len__(self) -> int:
        if not hasattr(self.dataset, "__len__"):
            raise TypeError(f"the wrapped {type(self.dataset).__name__} has no length")
        return self.policy.copies * len(self.dataset)

    def __repr__(self) -> str:
        return self._describe(self.dataset)


class IndexedDataset(Dataset):
    """Returns ``(index, sample)``: the indices :class:`BatchDegrade` needs to degrade a batch like the dataset path.

    Examples:
        >>> IndexedDataset(["a", "b"])[1]
        (1, 'b')
    """

    def __init__(self, dataset: Sequence[Any] | Dataset) -> None:
        if not (hasattr(dataset, "__getitem__") and hasattr(dataset, "__len__")):
            raise TypeError(f"dataset must be map-style (__getitem__ and __len__), got {type(dataset).__name__}")
        self.dataset = dataset

    def __len__(self) -> int:
        return len(self.dataset)

    def __getitem__(self, index: int) -> tuple[int, Any]:
        return operator.index(index), self.dataset[index]

    def __getattr__(self, name: str) -> Any:
        inner = self.__dict__.get("dataset")
        if inner is None or name.startswith("__"):
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        return getattr(inner, name)
