"""Measurement helpers on images: luma, a 2-D Hann window, local means, gradient energy and flat-pixel masks.

Shared by the fitters (effects), registration (fitting) and the gap statistics (diagnose), so each exists once.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

__all__ = [
    "CHANNEL_SPREAD",
    "FLAT_ERODE",
    "FLAT_LEVELS",
    "FLAT_SIGMA",
    "LUMA_WEIGHTS",
    "MIN_NOISE_SPREAD",
    "NOISE_GRADIENT_PIXELS",
    "NOISE_HIGH_PASS",
    "NOISE_ROBUST_SIGMAS",
    "NOISE_TILE",
    "NOISE_TILE_QUANTILE",
    "RAYLEIGH_Q99_OVER_MEDIAN",
    "box_mean",
    "channel_edges",
    "flat_mask",
    "flattest_window",
    "gaussian_gradient_magnitude",
    "gaussian_gradients",
    "gradient_energy",
    "hann2d",
    "high_pass",
    "luma",
    "noisy_flat_mask",
    "radial_frequency",
    "relative_flat_mask",
]

#: Rec. 601 luma weights of R, G, B.
LUMA_WEIGHTS = (0.299, 0.587, 0.114)


def luma(image: Tensor) -> Tensor:
    """``[..., 3, H, W]`` → ``[..., H, W]``: the Rec. 601 weighted sum of the channels, in the input's dtype."""
    weights = torch.tensor(LUMA_WEIGHTS, dtype=image.dtype, device=image.device)
    return (image * weights[:, None, None]).sum(-3)


def hann2d(height: int, width: int, dtype: torch.dtype = torch.float32, device: torch.device | None = None) -> Tensor:
    """``(H, W)`` outer product of two symmetric Hann windows (zero at the borders): tapers an image before an FFT."""
    rows = torch.hann_window(height, periodic=False, dtype=dtype, device=device)
    cols = torch.hann_window(width, periodic=False, dtype=dtype, device=device)
    return rows[:, None] * cols[None, :]


def radial_frequency(height: int, width: int, dtype: torch.dtype = torch.float32) -> Tensor:
    """``(H, W // 2 + 1)`` radial frequency (cycles/pixel) of each ``rfft2`` coefficient of an ``H × W`` frame."""
    rows = torch.fft.fftfreq(height, dtype=dtype)[:, None]
    cols = torch.fft.rfftfreq(width, dtype=dtype)[None, :]
    return torch.sqrt(rows**2 + cols**2)


def box_mean(image: Tensor, size: int) -> Tensor:
    """Local mean over a ``size × size`` window (``[..., H, W]``, odd ``size``), edges averaged over the valid part."""
    # separable: the mean over the valid rectangle is the mean of the row means
    return _window_mean(_window_mean(image, size, -1), size, -2)


def _window_mean(image: Tensor, size: int, dim: int) -> Tensor:
    """The mean over ``size`` neighbours along ``dim`` (the valid ones at the edges): the window's values added in
    order and divided by their count, the same bytes as ``avg_pool2d(..., count_include_pad=False)`` and a few times
    faster on the CPU for small windows (its kernel walks the window per output pixel)."""
    half, length = size // 2, image.shape[dim]
    padding = (half, half) if dim == -1 else (0, 0, half, half)
    padded = F.pad(image.reshape(-1, *image.shape[-2:]), padding)
    total = padded.narrow(dim, 0, length).clone()
    for offset in range(1, size):
        total += padded.narrow(dim, offset, length)
    count = F.pad(image.new_ones(length), (half, half)).unfold(0, size, 1).sum(1)
    return (total / (count if dim == -1 else count[:, None])).reshape(image.shape)


def high_pass(image: Tensor, size: int = 9) -> Tensor:
    """``image`` minus its ``size × size`` local mean: removes smooth content and keeps per-pixel fluctuations."""
    return image - box_mean(image, size)


def gradient_energy(image: Tensor) -> Tensor:
    """``(..., H, W)`` squared finite-difference gradient, summed over channels (zero on the last row/column)."""
    dx = F.pad(image[..., :, 1:] - image[..., :, :-1], (0, 1, 0, 0))
    dy = F.pad(image[..., 1:, :] - image[..., :-1, :], (0, 0, 0, 1))
    return (dx.pow(2) + dy.pow(2)).sum(-3)


def relative_flat_mask(clean: Tensor, quantile: float = 0.5) -> Tensor:
    """``(H, W)`` pixels whose local luma gradient energy (5×5 mean) is in the flattest ``quantile`` of the image.

    Relative to the image: in a detailed scene the flattest half still holds texture. Measure noise with
    :func:`flat_mask` instead; this mask suits statistics that only need the calmer part of a frame.
    """
    gray = luma(clean)
    gx = F.pad(gray[:, 1:] - gray[:, :-1], (0, 1))
    gy = F.pad(gray[1:, :] - gray[:-1, :], (0, 0, 0, 1))
    energy = box_mean(gx.pow(2) + gy.pow(2), 5)
    if quantile >= 1:
        return torch.ones_like(energy, dtype=torch.bool)
    threshold = torch.quantile(energy.flatten()[:: max(1, energy.numel() // 50_000)], quantile)
    return energy <= threshold


#: :func:`flat_mask`'s defaults: the clean image's gradient magnitude (Gaussian derivative at ``FLAT_SIGMA`` px,
#: channel mean) below ``FLAT_LEVELS`` 8-bit levels per pixel, the mask then eroded by ``FLAT_ERODE`` px.
FLAT_LEVELS = 1.5
FLAT_SIGMA = 2.0
FLAT_ERODE = 8
#: A single channel's gradient may be this many times ``FLAT_LEVELS`` (√3: its independent noise over their mean's).
CHANNEL_SPREAD = 3**0.5


def gaussian_gradient_magnitude(image: Tensor, sigma: float) -> Tensor:
    """``[..., H, W]`` → the same: magnitude of the image's gradient through Gaussian derivatives (σ in pixels,
    taps out to 4σ, edges replicated)."""
    gx, gy = gaussian_gradients(image, sigma)
    return torch.sqrt(gx * gx + gy * gy)


def gaussian_gradients(image: Tensor, sigma: float, *, point_reflected: bool = False) -> tuple[Tensor, Tensor]:
    """``[..., H, W]`` → its horizontal and vertical Gaussian derivatives (σ in pixels, taps out to 4σ), each of the
    image's shape. Beyond the frame the image is its edge replicated, or with ``point_reflected`` ``2·edge − mirror``
    (a linear or bilinear ramp goes on as it was, so its gradient stays the same up to the frame's edge)."""
    radius = max(1, int(4.0 * sigma + 0.5))
    offsets = torch.arange(-radius, radius + 1, dtype=image.dtype, device=image.device)
    gauss = torch.exp(-0.5 * (offsets / sigma) ** 2)
    gauss = gauss / gauss.sum()
    derivative = -offsets / sigma**2 * gauss
    flat = image.reshape(-1, 1, *image.shape[-2:])
    rows, cols = (min(radius, side - 1) if point_reflected else 0 for side in image.shape[-2:])
    flat = _point_reflected(_point_reflected(flat, cols, -1), rows, -2)
    flat = F.pad(flat, (radius - cols, radius - cols, radius - rows, radius - rows), mode="replicate")

    def separable(rows: Tensor, cols: Tensor) -> Tensor:
        out = F.conv2d(flat, cols.view(1, 1, 1, -1))
        return F.conv2d(out, rows.view(1, 1, -1, 1))

    gx, gy = separable(gauss, derivative), separable(derivative, gauss)
    return gx.reshape(image.shape), gy.reshape(image.shape)


def _point_reflected(image: Tensor, width: int, dim: int) -> Tensor:
    """``image`` extended by ``width`` (< its side) pixels at both ends of ``dim`` with ``2·edge − mirror``."""
    if width < 1:
        return image
    length = image.shape[dim]
    before = 2 * image.narrow(dim, 0, 1) - image.narrow(dim, 1, width).flip(dim)
    after = 2 * image.narrow(dim, length - 1, 1) - image.narrow(dim, length - 1 - width, width).flip(dim)
    return torch.cat([before, image, after], dim)


def flat_mask(clean: Tensor, levels: float = FLAT_LEVELS, sigma: float = FLAT_SIGMA, erode: int = FLAT_ERODE) -> Tensor:
    """``(H, W)`` pixels where the clean image ``(3, H, W)`` (float in [0, 1]) is flat in absolute terms.

    Its gradient magnitude (channel mean, Gaussian derivatives at ``sigma``) is below ``levels`` 8-bit levels, every
    channel holds no edge (:func:`channel_edges`), and so at every pixel within ``erode`` steps (4-connected; the
    frame's border counts as not flat). Unlike a share of the flattest pixels, this keeps texture out whatever the
    scene: a detailed city frame may hold none. Noise measured here is noise, not the misfit of a model at edges.

    Each channel too, not only their mean: an edge between two colours of the same channel mean (a red door on a
    blue wall) is flat in the mean, and its step, which the noise statistics measure per channel, read as noise of
    10–20 levels on the foreign cameras' walls (docs/results.md, "Noise the flat-noise statistic did not see").
    """
    return _eroded(_calm(clean, levels, sigma), erode)


def _calm(image: Tensor, levels: float, sigma: float) -> Tensor:
    """``(H, W)``: the gradient (at ``sigma``) of the channel mean below ``levels``, and no channel's edge."""
    mean = gaussian_gradient_magnitude(image.mean(-3) * 255.0, sigma)
    return (mean < levels) & ~channel_edges(image, CHANNEL_SPREAD * levels, sigma)


def channel_edges(image: Tensor, levels: float, sigma: float = FLAT_SIGMA) -> Tensor:
    """``(H, W)`` pixels of ``image`` ``(3, H, W)`` (float in [0, 1]) where some channel has an edge: its gradient
    (Gaussian derivatives at ``sigma``, :func:`gaussian_gradients`) is ``levels`` 8-bit levels or more, and so is
    that gradient less its :data:`NOISE_HIGH_PASS` local mean. A smooth colour ramp is no edge, however steep.

    The gradient less its local mean is the gradient of the image's high pass (away from the frame's border), and the
    noise statistics read each channel after that high pass (``noise_stats.HIGH_PASS``): a box mean removes a linear
    or bilinear ramp exactly (the mean of ``a + bx + cy + dxy`` over a window centred on a pixel is its value there),
    so a ramp adds nothing to the noise read; a step survives it, within ``NOISE_HIGH_PASS // 2`` pixels. The raw
    gradient of each channel alone cannot tell them apart: a smooth random-colour ramp climbs 3–6 levels a pixel in
    each channel while the channel mean stays flat, and a bound on it left such frames without flat pixels (a
    noise-only camera got no noise stage). A ramp's gradient is constant (or linear in the position), so it is
    removed up to the frame's border, where the derivatives continue the image by point reflection and the local
    mean is that of the window's part inside the frame. The raw gradient too, because the high pass spreads a step's
    mark over the whole window (its local mean takes ``h / 17`` a pixel of a step of ``h``): alone, with the erosion,
    it took a quarter of the foreign walls' flat pixels off, 13–16 px from an edge, beyond the statistic's reach.
    A step of ``h`` reads 0.20 ``h`` raw and 0.14 ``h`` high-passed at ``sigma`` 2; at the default bound (√3 × 1.5
    levels: a channel carries √3 times the independent noise of their mean, so noise in a clean image moves this
    test no more than the mean's) steps of 19 levels and more are edges.
    """
    gx, gy = gaussian_gradients(image * 255.0, sigma, point_reflected=True)
    steep = gx * gx + gy * gy >= levels * levels
    gx, gy = gx - box_mean(gx, NOISE_HIGH_PASS), gy - box_mean(gy, NOISE_HIGH_PASS)
    return (steep & (gx * gx + gy * gy >= levels * levels)).any(-3)


#: The gradient magnitude of 2-D Gaussian noise is Rayleigh-distributed: its 99 % quantile is
#: sqrt(2 ln 100) / sqrt(2 ln 2) = 2.58 times its median, and its 90 % quantile 1.82 times.
RAYLEIGH_Q99_OVER_MEDIAN = 2.58
#: Below this 90 %-to-median ratio the gradients are not noise's but a fine periodic texture's (a sine: about 1.3).
MIN_NOISE_SPREAD = 1.6
#: Where an image is flat at these σ (px, the first with enough pixels), its own noise barely moves the gradient
#: even at 20 levels (SIDD); the second serves noise correlated over several pixels at 30 levels and more.
NOISE_ROBUST_SIGMAS = (4.0, 8.0)
#: The local mean removed before noise is read (17×17: real noise is correlated over a few pixels; a smaller window
#: would remove part of it): the noise statistics' high pass (``noise_stats.HIGH_PASS``), whose gradient
#: :func:`noisy_flat_mask` reads as the noise's.
NOISE_HIGH_PASS = 17
#: Fewer pixels flat at a robust σ than this and the noise's gradient is not read there.
NOISE_GRADIENT_PIXELS = 2000
#: The noise's gradient is read per tile of this side, and the tiles' medians are ranked: fine texture that stays
#: flat at σ 4 raises some tiles, and the lower quartile is the noise's.
NOISE_TILE = 32
NOISE_TILE_QUANTILE = 0.25


def noisy_flat_mask(image: Tensor) -> Tensor:
    """:func:`flat_mask` of an image that carries its own noise (a capture, with no clean reference).

    A strong noise moves the gradient itself: at :data:`FLAT_LEVELS` the mask then keeps only the pixels where the
    noise happens to be calm, and the noise read there is too low (the SIDD phones' captures by 2.4×). Here the
    threshold is at least the 99 % quantile of the gradient the image's own noise makes: its high pass's gradient
    where the image is flat at a robust σ (:data:`NOISE_ROBUST_SIGMAS`), the lower quartile of :data:`NOISE_TILE`
    tiles' medians, and only when those gradients spread as noise's do (:data:`MIN_NOISE_SPREAD`). Noise of a few
    levels leaves it at :data:`FLAT_LEVELS`. The channel mean's gradient alone (not each channel's edges,
    :func:`channel_edges`, as :func:`flat_mask` also asks): the maximum of three channels' noise gradients, eroded,
    keeps too few pixels of a strongly noisy capture (8 levels of correlated noise: 4,164 of 15,051), so a colour
    edge of the same channel mean is still read as flat here.
    """
    gray = image.mean(-3) * 255.0
    threshold = max(FLAT_LEVELS, RAYLEIGH_Q99_OVER_MEDIAN * _noise_gradient_median(image, gray))
    return _eroded(gaussian_gradient_magnitude(gray, FLAT_SIGMA) < threshold, FLAT_ERODE)


def _noise_gradient_median(image: Tensor, gray: Tensor) -> float:
    """The median gradient magnitude (at :data:`FLAT_SIGMA`) of the image's own noise, or 0 where not readable."""
    for sigma in NOISE_ROBUST_SIGMAS:
        robust = flat_mask(image, sigma=sigma)
        if int(robust.sum()) >= NOISE_GRADIENT_PIXELS:
            break
    else:
        return 0.0
    gradient = gaussian_gradient_magnitude(high_pass(gray, NOISE_HIGH_PASS), FLAT_SIGMA)
    tiles = _tiles(torch.where(robust, gradient, torch.nan))
    tiles = tiles[(~tiles.isnan()).sum(1) >= NOISE_TILE * NOISE_TILE // 4]
    if not len(tiles):
        return 0.0
    values = gradient[robust][:: max(1, int(robust.sum()) // 200_000)]
    spread = float(torch.quantile(values, 0.9)) / max(float(values.median()), 1e-12)
    medians = tiles.nanmedian(1).values
    return float(torch.quantile(medians, NOISE_TILE_QUANTILE)) if spread >= MIN_NOISE_SPREAD else 0.0


def _tiles(values: Tensor) -> Tensor:
    """``(H, W)`` cut into whole :data:`NOISE_TILE` squares: ``(tiles, NOISE_TILE²)``."""
    height, width = (side // NOISE_TILE * NOISE_TILE for side in values.shape[-2:])
    cut = values[:height, :width].reshape(height // NOISE_TILE, NOISE_TILE, width // NOISE_TILE, NOISE_TILE)
    return cut.permute(0, 2, 1, 3).reshape(-1, NOISE_TILE * NOISE_TILE)


def _eroded(mask: Tensor, steps: int) -> Tensor:
    """``mask`` eroded ``steps`` times (4-connected; the frame's border counts as outside)."""
    for _ in range(steps):
        inner = torch.zeros_like(mask)
        inner[1:-1, 1:-1] = mask[1:-1, 1:-1] & mask[:-2, 1:-1] & mask[2:, 1:-1] & mask[1:-1, :-2] & mask[1:-1, 2:]
        mask = inner
    return mask


def flattest_window(clean: Tensor, side: int, step: int = 8) -> tuple[tuple[slice, slice], float]:
    """The ``side × side`` window (corners on a ``step``-pixel grid) of ``clean`` (``(3, H, W)``, float in [0, 1])
    holding the most :func:`flat_mask` pixels, as ``((rows, cols), share of it that is flat)``. ``side`` is cut to
    the image; cut a pair with ``image[(slice(None), *window)]``. Noise shows first, and is measurable, there."""
    side = min(side, *clean.shape[-2:])
    pooled = F.avg_pool2d(flat_mask(clean).float()[None, None], side, stride=step)[0, 0]
    top, left = divmod(int(pooled.argmax()), pooled.shape[1])
    top, left = top * step, left * step
    return (slice(top, top + side), slice(left, left + side)), float(pooled.max())
