"""Shared machinery of the effect fitters: pair normalisation, alignment, crops and the optimiser loop."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade._support.pixels import as_unit
from camdegrade.effects.base import Pairs
from camdegrade.functional.analysis.images import gradient_energy

PairList = list[tuple[Tensor, Tensor]]


def _as_list(images: Pairs, name: str) -> list[Tensor]:
    if isinstance(images, Tensor):
        if images.ndim == 3:
            return [images]
        if images.ndim == 4:
            return list(images)
        raise ValueError(f"{name} must be (3, H, W) or (N, 3, H, W), got shape {tuple(images.shape)}")
    if isinstance(images, Sequence) and not isinstance(images, str):
        return list(images)
    raise TypeError(f"{name} must be a tensor or a sequence of (3, H, W) tensors, got {type(images).__name__}")


def _as_float(image: Tensor, name: str) -> Tensor:
    if not isinstance(image, Tensor) or image.ndim != 3 or image.shape[0] != 3:
        shape = tuple(image.shape) if isinstance(image, Tensor) else type(image).__name__
        raise ValueError(f"{name} must hold (3, H, W) images, got {shape}")
    if image.dtype != torch.uint8 and not image.is_floating_point():
        raise TypeError(f"{name} must be uint8 or float images, got dtype {image.dtype}")
    return as_unit(image.detach().cpu())


def as_pairs(source: Pairs, target: Pairs) -> PairList:
    """Validated ``(source, target)`` float32 CPU pairs, each ``(3, H, W)`` with matching sizes.

    Fitting runs on the CPU: the estimators are small, and their results must not depend on the device.
    """
    sources, targets = _as_list(source, "source"), _as_list(target, "target")
    if len(sources) != len(targets) or not sources:
        raise ValueError(
            f"source and target must hold the same non-zero number of images, got {len(sources)} and {len(targets)}"
        )
    pairs = []
    for index, (src, tgt) in enumerate(zip(sources, targets, strict=True)):
        src, tgt = _as_float(src, "source"), _as_float(tgt, "target")
        if src.shape != tgt.shape:
            raise ValueError(
                f"pair {index}: source and target must have the same shape, "
                f"got {tuple(src.shape)} and {tuple(tgt.shape)}"
            )
        pairs.append((src, tgt))
    return pairs


def huber_weights(residual: Tensor) -> Tensor:
    """Iteratively-reweighted-least-squares weights of Huber's loss: 1 inside 1.345 robust σ (σ from the median
    absolute residual), falling as 1/|r| outside.

    References:
        P. J. Huber, "Robust Estimation of a Location Parameter", Annals of Mathematical Statistics 35(1), 1964;
        P. W. Holland, R. E. Welsch, "Robust regression using iteratively reweighted least-squares",
        Communications in Statistics 6(9), 1977.
    """
    scale = 1.4826 * residual.median().clamp_min(1e-12)
    return (1.345 * scale / residual.clamp_min(1e-15)).clamp(max=1.0)


def robust_lstsq(design: Tensor, targets: Tensor, iterations: int) -> Tensor:
    """``solution`` with ``design @ solution ≈ targets`` (``(n, p)``, ``(n, k)`` → ``(p, k)``), robust to outliers:
    least squares reweighted ``iterations`` times with Huber weights on each row's residual norm."""
    weights = torch.ones(design.shape[0], dtype=design.dtype, device=design.device)
    solution = torch.zeros(design.shape[1], targets.shape[1], dtype=design.dtype, device=design.device)
    for _ in range(max(1, iterations)):
        root = weights.sqrt()[:, None]
        solution = torch.linalg.lstsq(design * root, targets * root).solution
        weights = huber_weights((targets - design @ solution).norm(dim=1))
    return solution


def downscale(image: Tensor, max_side: int) -> Tensor:
    """Area-average ``[..., 3, H, W]`` so that its longer side is at most ``max_side`` (a low-pass filter)."""
    height, width = image.shape[-2:]
    factor = max(height, width) / max_side
    if factor <= 1:
        return image
    size = (max(1, round(height / factor)), max(1, round(width / factor)))
    flat = image.reshape(-1, *image.shape[-3:])
    return F.interpolate(flat, size=size, mode="area").reshape(*image.shape[:-2], *size)


def affine_residual(predicted: Tensor, target: Tensor, groups: int = 1) -> Tensor:
    """``a · predicted + c − target`` with the per-group, per-channel ``(a, c)`` that minimise it (closed form).

    ``predicted``/``target`` are ``(G·k, 3, h, w)``: ``G`` groups (pairs) of ``k`` images each. Projecting
    out an affine colour map inside the loss (variable projection) keeps the slight tone/colour shift of real
    pairs from biasing a spatial fit, without the regression dilution of aligning on low-passed images first.
    """
    shape = predicted.shape
    p = predicted.reshape(groups, -1, 3, *shape[-2:]).transpose(1, 2).reshape(groups, 3, -1)
    t = target.reshape(groups, -1, 3, *shape[-2:]).transpose(1, 2).reshape(groups, 3, -1)
    p_centered = p - p.mean(-1, keepdim=True)
    t_centered = t - t.mean(-1, keepdim=True)
    gain = (p_centered * t_centered).mean(-1, keepdim=True) / p_centered.pow(2).mean(-1, keepdim=True).clamp_min(1e-12)
    return gain * p_centered - t_centered


def textured_crops(pairs: PairList, size: int, per_image: int, margin: int = 0) -> tuple[Tensor, Tensor, int]:
    """The most textured ``size + 2·margin`` square crops of each pair, as two stacked batches.

    Texture is what constrains blur and warps; flat crops only add cost. Every pair contributes the same
    number of crops (at most ``per_image``), grouped pair by pair, so the third value (the number of pairs
    used) splits the batch back into pairs. Pairs too small for one crop are left out.
    """
    full = size + 2 * margin
    stride = max(1, size // 2)
    energies = []
    for src, tgt in pairs:
        if min(src.shape[-2:]) >= full:
            energy = F.avg_pool2d(gradient_energy(src)[None, None], kernel_size=full, stride=stride)[0, 0]
            energies.append((src, tgt, energy))
    if not energies:
        sizes = ", ".join(f"{src.shape[-2]}x{src.shape[-1]}" for src, _ in pairs)
        raise ValueError(f"images must be at least {full} pixels on each side to fit, got {sizes}")
    count = min(per_image, *(energy.numel() for _, _, energy in energies))
    sources, targets = [], []
    for src, tgt, energy in energies:
        for index in torch.argsort(energy.flatten(), descending=True)[:count].tolist():
            top, left = divmod(index, energy.shape[1])
            top, left = top * stride, left * stride
            sources.append(src[:, top : top + full, left : left + full])
            targets.append(tgt[:, top : top + full, left : left + full])
    return torch.stack(sources), torch.stack(targets), len(energies)


def minimize(parameters: Sequence[Tensor], loss_fn: Callable[[], Tensor], max_iter: int = 60) -> float:
    """Minimise ``loss_fn`` over ``parameters`` (leaf tensors, ``requires_grad``) with L-BFGS; return the loss."""
    optimizer = torch.optim.LBFGS(
        list(parameters), lr=1.0, max_iter=max_iter, line_search_fn="strong_wolfe", tolerance_change=1e-12
    )

    def closure() -> Tensor:
        optimizer.zero_grad()
        loss = loss_fn()
        loss.backward()
        return loss

    optimizer.step(closure)
    with torch.no_grad():
        final = float(loss_fn())
    if not math.isfinite(final):
        raise RuntimeError("the fit diverged (non-finite loss); check that the pairs are aligned and in [0, 1]")
    return final


def grid_search(candidates: Sequence[float], loss_fn: Callable[[float], float]) -> float:
    """The candidate with the lowest loss (a robust initialisation before a local optimiser)."""
    losses = [loss_fn(value) for value in candidates]
    return candidates[min(range(len(losses)), key=losses.__getitem__)]
