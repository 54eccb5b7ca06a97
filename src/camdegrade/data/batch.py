"""``BatchDegrade``: degrade a collated batch on its own device, matching the per-sample dataset path."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from camdegrade.data._keys import SharedEpoch, check_epoch, item_generator
from camdegrade.data.datasets import DegradeLike, as_camera_degrade, resolve_seed
from camdegrade.data.policies import Bernoulli, MixPolicy
from camdegrade.engine import check_image_shape, check_image_tensor, degrade_selected
from camdegrade.profile import EffectParams

__all__ = ["BatchDegrade"]


class BatchDegrade(nn.Module):
    """Degrade some images of a collated batch, on the batch's device, after the DataLoader.

    For training loops where per-sample degradation in CPU workers is the bottleneck: load clean images, move the
    batch to the GPU, then call this module. Decisions and random values are drawn per sample from the same
    (seed, epoch, index) keys the dataset path uses, so with the dataset indices (see :class:`IndexedDataset`) the
    output equals what ``DegradedDataset(dataset, degrade, Bernoulli(p), seed)`` returns for those items (up to
    floating-point differences between batched and single-image convolutions). The profile runs on the whole
    batch and ``torch.where`` picks each sample's view, so shapes never depend on the decisions.

    Args:
        degrade: a :class:`~camdegrade.CameraDegrade`, a :class:`~camdegrade.CameraProfile`, a built-in profile
            name or a profile path. The profile is copied to each device it meets, once.
        p: probability that each sample is degraded, or a one-view policy (:class:`Bernoulli`, :class:`Ratio`,
            :class:`Alternate`, :class:`Schedule`) deciding per index.
        seed: as for :class:`DegradedDataset`; use the same value for the same results.

    Shape:
        - Input: ``(B, 3, H, W)`` uint8, or float in ``[0, 1]``, on any device.
        - Output: same shape, dtype and device.

    Examples:
        >>> from camdegrade import CameraProfile, DomainShiftNet
        >>> batch_degrade = BatchDegrade(CameraProfile(DomainShiftNet()), p=0.5, seed=0)
        >>> images = torch.zeros(4, 3, 8, 8, dtype=torch.uint8)
        >>> batch_degrade(images, indices=torch.arange(4), epoch=0).shape
        torch.Size([4, 3, 8, 8])
    """

    def __init__(self, degrade: DegradeLike, p: float | MixPolicy = 0.5, seed: int | None = None) -> None:
        super().__init__()
        self.degrade = as_camera_degrade(degrade)
        self.policy = _one_view_policy(p)
        self.seed = resolve_seed(seed)
        self._epoch = SharedEpoch()
        self._next_index = 0

    def set_epoch(self, epoch: int) -> None:
        """The epoch used when :meth:`forward` gets none; also restarts the numbering of index-less batches."""
        self._epoch.set(epoch)
        self._next_index = 0

    def decisions(self, indices: Sequence[int], epoch: int) -> Tensor:
        """``(B,)`` bool on the CPU: which of the items ``indices`` are degraded in ``epoch``."""
        return torch.tensor([bool(self.policy.decide(i, 0, epoch, self.seed)) for i in indices], dtype=torch.bool)

    def make_params(self, shape: tuple[int, int, int], indices: Sequence[int], epoch: int) -> EffectParams:
        """Every effect's random values for items ``indices`` of ``shape = (3, H, W)`` in ``epoch``, each drawn
        from that item's generator exactly as the dataset path draws it, concatenated along the batch."""
        probe = torch.zeros((), dtype=torch.uint8).expand(shape)
        per_item = [
            self.degrade.draw_params([probe], item_generator(self.seed, epoch, i), p=1.0)["effects"] for i in indices
        ]
        if not per_item:
            return self.degrade.profile.make_params((0, *shape), torch.Generator())
        return [
            {key: torch.cat([item[stage][key] for item in per_item]) for key in per_item[0][stage]}
            for stage in range(len(per_item[0]))
        ]

    def forward(
        self, images: Tensor, indices: Tensor | Sequence[int] | None = None, epoch: int | None = None
    ) -> Tensor:
        """Degrade the items ``indices`` (dataset indices, one per image) of ``images`` as in ``epoch``.

        Without ``indices``, images are numbered consecutively across calls from 0 (restarted by
        :meth:`set_epoch`): reproducible for a fixed call order, but not tied to dataset items. Without ``epoch``,
        the last :meth:`set_epoch` value (0 at first) is used.
        """
        _check_batch(images)
        batch = images.shape[0]
        epoch = self._epoch.get() if epoch is None else check_epoch(epoch)
        index_list = self._index_list(indices, batch)
        if images.numel() == 0:  # empty in, empty out
            return images
        apply = self.decisions(index_list, epoch)
        params = self.make_params(tuple(images.shape[1:]), index_list, epoch)
        profile = self.degrade.profile_on(images.device)
        return degrade_selected(profile, images, apply, params, self.degrade.precision)

    def _index_list(self, indices: Tensor | Sequence[int] | None, batch: int) -> list[int]:
        if indices is None:
            start, self._next_index = self._next_index, self._next_index + batch
            return list(range(start, start + batch))
        index_list = indices.tolist() if isinstance(indices, Tensor) else list(indices)
        if len(index_list) != batch or not all(isinstance(i, int) and not isinstance(i, bool) for i in index_list):
            raise ValueError(
                f"indices must hold one integer dataset index per image ({batch}), got {len(index_list)} values "
                f"of types {sorted({type(i).__name__ for i in index_list})}"
            )
        return index_list

    def extra_repr(self) -> str:
        return f"profile={self.degrade.profile.name!r}, policy={self.policy!r}, seed={self.seed}"


def _one_view_policy(p: float | MixPolicy) -> MixPolicy:
    if isinstance(p, MixPolicy):
        if p.copies != 1 or isinstance(p.decide(0, 0, 0, 0), tuple):
            raise ValueError(
                f"p must be a probability or a one-view policy (Bernoulli, Ratio, Alternate, Schedule), got {p!r}; "
                "Union and PairedViews change which images a batch holds, so use them with DegradedDataset"
            )
        return p
    return Bernoulli(p)


def _check_batch(images: Tensor) -> None:
    if not isinstance(images, Tensor):
        raise TypeError(f"images must be a tensor (B, 3, H, W), got {type(images).__name__}")
    check_image_shape(images, "BatchDegrade()")
    if images.ndim != 4:
        raise ValueError(f"images must be a batch shaped (B, 3, H, W), got shape {tuple(images.shape)}")
    check_image_tensor(images, "BatchDegrade()")
