"""The least-squares loss the ISP detail stages (sharpening, noise reduction) are fitted by: the stage's output on the
most textured crops of the source against the target, as a function of the Gaussian's sigma and the stage's own
values, with the detail of each fixed sigma computed once."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from torch import Tensor

from camdegrade.effects._fitting import PairList, affine_residual, textured_crops
from camdegrade.effects.optics.blur import fit_margin
from camdegrade.functional import blur_planes
from camdegrade.functional.analysis.images import luma as luma_of

#: ``(inner, detail, *values) → output``: the stage applied to the crops given their detail.
Combine = Callable[..., Tensor]


def crop_options(images: Sequence[Tensor], max_sigma: float) -> dict[str, Any]:
    """Fit options for sigmas up to ``max_sigma``: crops as large as the smallest image allows (16 to 64 px), so
    that small images are fitted on small crops rather than refused."""
    side = min(min(image.shape[-2:]) for image in images)
    return {"max_sigma": max_sigma, "crop": max(16, min(64, side - 2 * fit_margin(max_sigma)))}


def detail_loss(
    pairs: PairList, crop: int, crops_per_image: int, margin: int, *, luma: bool, align: bool, combine: Combine
) -> Callable[..., Tensor]:
    """Mean squared error of ``combine(source, detail_σ(source), *values)`` (clipped to [0, 1]) against the target
    on the most textured crops, as a function of ``(sigma, *values)``; with ``align``, a per-pair affine colour map
    is projected out, so that the tone shift of real pairs does not read as detail."""
    src, tgt, groups = textured_crops(pairs, crop, crops_per_image, margin)
    src, tgt = src.double(), tgt[..., margin:-margin, margin:-margin].double()
    inner = src[..., margin:-margin, margin:-margin]
    planes = luma_of(src) if luma else src.flatten(0, 1)  # the planes whose detail is taken, one by one
    details: dict[float, Tensor] = {}

    def detail_of(sigma: Tensor) -> Tensor:
        """The cropped detail at ``sigma``; cached for the grid's fixed sigmas (no graph to keep)."""
        if sigma.requires_grad:
            return cropped_detail(sigma)
        key = float(sigma)
        if key not in details:
            details[key] = cropped_detail(sigma)
        return details[key]

    def cropped_detail(sigma: Tensor) -> Tensor:
        detail = (planes - blur_planes(planes, sigma))[..., margin:-margin, margin:-margin]
        return detail.reshape(inner.shape[0], 1 if luma else 3, *inner.shape[-2:])

    def loss_of(sigma: Tensor, *values: Tensor) -> Tensor:
        output = combine(inner, detail_of(sigma), *values).clamp(0.0, 1.0)
        residual = affine_residual(output, tgt, groups=groups) if align else output - tgt
        return residual.pow(2).mean()

    return loss_of
