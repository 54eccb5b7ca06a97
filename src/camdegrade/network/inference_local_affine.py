"""The local-affine network's CPU plan: :class:`~camdegrade.network.LocalAffineNet`'s arithmetic for inference."""

from __future__ import annotations

import functools

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade._support.pixels import bytes_to_unit
from camdegrade.network._onednn import FUSED_LINEAR, conv_relu, live_linear_relu, use_fused_kernels
from camdegrade.network.nets import (
    FIELD_SMOOTHING,
    SIZE_MULTIPLE,
    LocalAffineNet,
    check_batch,
    piecewise_linear,
    smoothed,
)

__all__ = [
    "BILINEAR_PHASES",
    "FILTER_UNROLL",
    "MATRIX_UPSAMPLING_BILINEAR_MAX",
    "MATRIX_UPSAMPLING_MAX",
    "ColourFilter",
    "CurveTable",
    "LocalAffineInference",
    "bilinear_upsampled",
    "byte_curve",
    "upsampled_field",
    "upsampling_matrix",
]


class LocalAffineInference:
    """:class:`~camdegrade.network.LocalAffineNet` for CPU inference: the module's arithmetic up to rounding, in
    about half its time.

    - The encoder runs as :class:`CpuInference`'s: plain NCHW input, channels-last weights, in ``dtype`` (in native
      bfloat16 with oneDNN's fused convolution + ReLU).
    - The two 1×1 decoder convolutions are matrix products over the encoder's pixels, in ``dtype``; the first leaves
      out the channels that ReLU left at zero over the whole image (most of them for a fitted profile on a
      photograph).
    - From the colour field on, everything is float32 whatever ``dtype`` (it carries the image's detail to the
      output): the field is upsampled by :func:`upsampled_field` (small matrix products up to 256² images) and
      applied in place, one plane product at a time, with no ``(3, 3, H, W)`` temporary; the 7×7 filter ``K`` runs
      as one convolution computing :data:`FILTER_UNROLL` adjacent pixels per position (:class:`ColourFilter`).
    - Images are computed one at a time, so each gets the same bytes alone as in any batch or chunk.

    About half the module's time in float32; measured against it and the paper network's plan in
    docs/performance.md, *The CPU plans' choices*.

    Args:
        network: the module; its weights are copied once (see :func:`cpu_inference`, which rebuilds the plan when
            they change).
        dtype: ``torch.float32`` or ``torch.bfloat16`` (the encoder and decoder's).
        fingerprint: the cache key of ``network``'s tensors the plan was built from.
    """

    def __init__(
        self, network: LocalAffineNet, dtype: torch.dtype = torch.float32, fingerprint: tuple[int, ...] = ()
    ) -> None:
        if dtype not in (torch.float32, torch.bfloat16):
            raise ValueError(f"dtype must be torch.float32 or torch.bfloat16, got dtype={dtype}")
        self.dtype = dtype
        self.fingerprint = fingerprint
        self.smooth = network.upsample == "smooth"
        self.curve = network.curve.detach().clone() if network.curves else None
        self._byte_curve = None if self.curve is None else byte_curve(self.curve[0])
        self._output_curve = None if self.curve is None else CurveTable(self.curve[1])
        self._fused = use_fused_kernels(dtype)
        channels_last = torch.channels_last
        with torch.no_grad():
            self.encode = [
                (
                    layer.weight.detach().to(dtype, copy=True).contiguous(memory_format=channels_last),
                    layer.bias.detach().to(dtype, copy=True),
                )
                for layer in (network.encode1, network.encode2)
            ]
            self.decode = [
                (layer.weight.detach().flatten(1).to(dtype, copy=True), layer.bias.detach().to(dtype, copy=True))
                for layer in (network.decode1, network.decode2)
            ]
            self.filter = ColourFilter(network.linear.weight.detach(), network.linear.bias.detach())

    def run(self, image: Tensor) -> Tensor:
        """``(N, 3, H, W)`` float in [0, 1] or uint8 → the network's float32 output, contiguous, same shape."""
        check_batch(image)
        n, _, height, width = image.shape
        pad_bottom, pad_right = -height % SIZE_MULTIPLE, -width % SIZE_MULTIPLE
        output = torch.empty(n, 3, height, width)
        with torch.no_grad():
            for index in range(n):
                one = image[index : index + 1]
                unit = bytes_to_unit(one) if one.dtype == torch.uint8 else one.float()
                curved = self._input_curve(one, unit)
                if pad_bottom or pad_right:
                    pad = (0, pad_right, 0, pad_bottom)
                    padded = F.pad(unit, pad, mode="replicate")
                    curved = padded if curved is unit else F.pad(curved, pad, mode="replicate")
                    unit = padded
                    output[index] = self._run_aligned(unit, curved)[0, :, :height, :width]
                else:
                    self._run_aligned(unit, curved, output[index : index + 1])
        return output

    def _input_curve(self, image: Tensor, unit: Tensor) -> Tensor:
        """``f(x)`` of one image (``unit`` itself without curves): a byte image by table lookup, the same values."""
        if self.curve is None:
            return unit
        if image.dtype == torch.uint8:
            # int32 indices: index_select reads them directly, where take needs int64 (docs/performance.md, *The
            # CPU plans' choices*); the same table, so the same values
            offsets = torch.arange(0, 3 * 256, 256, dtype=torch.int32).view(1, 3, 1, 1)
            index = image.to(torch.int32).add_(offsets).view(-1)
            return torch.index_select(self._byte_curve, 0, index).view(image.shape)
        return piecewise_linear(unit, self.curve[0])

    def _run_aligned(self, image: Tensor, curved: Tensor, out: Tensor | None = None) -> Tensor:
        """``clamp(g(A(x) · (K ∗ f(x)) + b(x)), 0, 1)`` for one ``(1, 3, H, W)`` image with H and W multiples of 4
        and ``curved`` = ``f(image)`` (``f`` and ``g`` the network's curves, or none: ``curved`` is ``image``),
        written into ``out`` (``(1, 3, H, W)`` float32, contiguous) when given."""
        hidden = image.to(self.dtype)
        for weight, bias in self.encode:
            hidden = conv_relu(hidden, weight, bias, self._fused)
        rows, cols = hidden.shape[-2:]
        pixels = hidden.permute(0, 2, 3, 1).reshape(rows * cols, -1)
        second, second_bias = self.decode[1]
        field = torch.addmm(second_bias, self._decode1(pixels), second.t()).float()
        field = upsampled_field(field.t().reshape(1, -1, rows, cols), self.smooth)
        filtered = self.filter(curved)
        mixed = torch.add(filtered, field[:, 9:], out=out if self._output_curve is None else None)
        planes, weights, inputs = mixed[0].unbind(0), field[0].unbind(0), filtered[0].unbind(0)
        for row in range(3):
            for column in range(3):
                planes[row].addcmul_(weights[3 * row + column], inputs[column])
        if self._output_curve is not None:
            mixed = self._output_curve(mixed, out)
        return mixed.clamp_(0.0, 1.0)

    def _decode1(self, pixels: Tensor) -> Tensor:
        """ReLU of the first decoder product for one image's encoder ``pixels`` ``(M, C)``: in float32 without the
        channels that are zero over the image; in bfloat16 whole (a column gather costs more than it saves there:
        see :meth:`CpuInference._decode1` and docs/performance.md, *The CPU plans' choices*)."""
        weight, bias = self.decode[0]
        if self.dtype == torch.float32:
            return live_linear_relu(pixels, weight, bias)
        if self._fused:
            return FUSED_LINEAR(pixels.contiguous(), weight, bias, "relu", [], "")
        return torch.addmm(bias, pixels, weight.t()).relu_()


#: The local-affine plan's 7×7 filter computes this many horizontally adjacent pixels of its 3 outputs at each
#: position of a convolution with a column stride of as many (15 output channels, 7 × 11 taps): oneDNN's float32
#: convolution costs about the same for 3 or 16 output channels, its time set by inputs × taps per position, so
#: this does the same arithmetic in about a third of the plain convolution's time, and faster than a product of
#: spectra (docs/performance.md, *The CPU plans' choices*).
FILTER_UNROLL = 5


class ColourFilter:
    """The network's full-resolution 7×7 filter ``K ∗ x`` (3 outputs from 3 inputs), the border replicated, as
    :meth:`LocalAffineNet.filtered` computes it: one convolution that computes :data:`FILTER_UNROLL` adjacent
    pixels per position (each output channel the filter shifted by one column), laid out as an image by one copy.
    The same products and sums as the plain convolution, so the same values (tested)."""

    def __init__(self, weight: Tensor, bias: Tensor) -> None:
        outputs, inputs, rows, cols = weight.shape
        unrolled = weight.new_zeros(outputs, FILTER_UNROLL, inputs, rows, cols + FILTER_UNROLL - 1)
        for shift in range(FILTER_UNROLL):
            unrolled[:, shift, :, :, shift : shift + cols] = weight
        self.half = cols // 2
        self.weight = unrolled.reshape(outputs * FILTER_UNROLL, inputs, rows, -1).float().contiguous()
        self.bias = bias.float().repeat_interleave(FILTER_UNROLL)

    def __call__(self, image: Tensor) -> Tensor:
        """``(1, 3, H, W)`` float32 → ``K ∗ image + bias``, ``(1, 3, H, W)`` float32 (a view into a frame as wide as
        the next multiple of :data:`FILTER_UNROLL`)."""
        height, width = image.shape[-2:]
        wide = -(-width // FILTER_UNROLL) * FILTER_UNROLL
        half = self.half
        padded = F.pad(image, (half, half + wide - width, half, half), mode="replicate")
        out = F.conv2d(padded, self.weight, self.bias, stride=(1, FILTER_UNROLL))
        out = out.reshape(1, 3, FILTER_UNROLL, height, wide // FILTER_UNROLL).permute(0, 1, 3, 4, 2)
        return out.reshape(1, 3, height, wide)[..., :width]


class CurveTable:
    """:func:`~camdegrade.network.piecewise_linear` through one set of knots ``(3, K)`` for inference: the same
    arithmetic on the same floats (each segment's low knot and its rise, precomputed, read with int32 indices: in
    about 40 % of its time, docs/performance.md, *The CPU plans' choices*), so the same values."""

    def __init__(self, knots: Tensor) -> None:
        self.segments = knots.shape[-1] - 1
        self.low = knots[:, :-1].contiguous().view(-1)
        self.rise = (knots[:, 1:] - knots[:, :-1]).contiguous().view(-1)

    def __call__(self, image: Tensor, out: Tensor | None = None) -> Tensor:
        """``(1, 3, H, W)`` float32 → each channel through its curve (a new tensor, or written into ``out``)."""
        position = image.clamp(0.0, 1.0).mul_(self.segments)
        index = position.floor().clamp_(max=self.segments - 1)
        weight = position.sub_(index)
        offsets = torch.arange(0, 3 * self.segments, self.segments, dtype=torch.int32).view(1, 3, 1, 1)
        flat = index.to(torch.int32).add_(offsets).reshape(-1)
        rise = torch.index_select(self.rise, 0, flat).view(image.shape).mul_(weight)
        return torch.add(rise, torch.index_select(self.low, 0, flat).view(image.shape), out=out)


#: Fields of at most this many rows and columns (images up to 256²) are upsampled by two small matrix products;
#: larger ones by interpolation, whose cost grows with the pixels alone: the products are faster up to here, and the
#: interpolation as fast from 128 rows (docs/performance.md, *The CPU plans' choices*).
MATRIX_UPSAMPLING_MAX = 64


def byte_curve(knots: Tensor) -> Tensor:
    """The curve through ``knots`` ``(3, K)`` at every byte value, per channel, flattened ``(3 · 256,)``: exactly what
    :func:`~camdegrade.network.piecewise_linear` gives a byte image read as ``value / 255`` (the same arithmetic on
    the same floats), in a lookup of about half its time (docs/performance.md, *The CPU plans' choices*)."""
    values = bytes_to_unit(torch.arange(256, dtype=torch.uint8)).expand(1, 3, 1, 256)
    return piecewise_linear(values, knots).reshape(-1)


#: Bilinear fields of more than this many rows or columns are upsampled by interpolating between neighbours
#: (:func:`bilinear_upsampled`), smaller ones by the matrix products: equal at 24 rows, the interpolation a quarter
#: of the products' time at 224² (docs/performance.md, *The CPU plans' choices*).
MATRIX_UPSAMPLING_BILINEAR_MAX = 24


def upsampled_field(field: Tensor, smooth: bool) -> Tensor:
    """The colour field ``(1, C, rows, cols)`` (contiguous) at full resolution, as :class:`LocalAffineNet` makes it:
    bilinear by :data:`~camdegrade.network.SIZE_MULTIPLE`, then with ``smooth`` its smoothing."""
    rows, cols = field.shape[-2:]
    if not smooth and max(rows, cols) > MATRIX_UPSAMPLING_BILINEAR_MAX:
        return bilinear_upsampled(field)
    if max(rows, cols) <= MATRIX_UPSAMPLING_MAX:
        down, across = upsampling_matrix(rows, smooth), upsampling_matrix(cols, smooth)
        return torch.matmul(down, torch.matmul(field[0], across.t()))[None]
    field = F.interpolate(field, scale_factor=SIZE_MULTIPLE, mode="bilinear", align_corners=False)
    return smoothed(field) if smooth else field


#: Output ``4i + k`` of a bilinear upsampling by 4 (half-pixel centres) lies between sources ``i − 1`` and ``i``
#: (k = 0, 1) or ``i`` and ``i + 1`` (k = 2, 3): per phase, where the first of the two sits in the border-replicated
#: line (0 or 1 past ``i``) and the weight of the second.
BILINEAR_PHASES = ((0, 0.625), (0, 0.875), (1, 0.125), (1, 0.375))


def bilinear_upsampled(field: Tensor) -> Tensor:
    """``field`` ``(1, C, rows, cols)`` upsampled bilinearly by 4 (half-pixel centres, the border replicated), as
    ``F.interpolate(..., mode="bilinear", align_corners=False)`` does, up to float32 rounding: each of the four
    phases of each axis is one interpolation between neighbours, written in place (columns first, so that the larger
    pass writes whole rows)."""
    planes = field[0]
    channels, rows, cols = planes.shape
    border = torch.cat((planes[..., :1], planes, planes[..., -1:]), dim=-1)
    across = planes.new_empty(channels, rows, cols, len(BILINEAR_PHASES))
    for phase, (start, weight) in enumerate(BILINEAR_PHASES):
        torch.lerp(
            border[..., start : start + cols], border[..., start + 1 : start + 1 + cols], weight, out=across[..., phase]
        )
    across = across.view(channels, rows, -1)
    border = torch.cat((across[:, :1], across, across[:, -1:]), dim=1)
    out = planes.new_empty(channels, rows, len(BILINEAR_PHASES), across.shape[-1])
    for phase, (start, weight) in enumerate(BILINEAR_PHASES):
        torch.lerp(
            border[:, start : start + rows], border[:, start + 1 : start + 1 + rows], weight, out=out[:, :, phase]
        )
    return out.view(1, channels, -1, across.shape[-1])


@functools.lru_cache(maxsize=2 * MATRIX_UPSAMPLING_MAX)
def upsampling_matrix(size: int, smooth: bool) -> Tensor:
    """The ``(4·size, size)`` matrix of :func:`upsampled_field` along one axis: bilinear with half-pixel centres (the
    source index clamped at the borders), then, with ``smooth``, :data:`~camdegrade.network.FIELD_SMOOTHING` with the
    border replicated (folded in, so it costs nothing more). Built in float64; cached (treat it as read-only)."""
    out = size * SIZE_MULTIPLE
    source = ((torch.arange(out, dtype=torch.float64) + 0.5) / SIZE_MULTIPLE - 0.5).clamp(min=0.0)
    low = source.floor().long().clamp(max=size - 1)
    fraction = source - low
    rows = torch.arange(out)
    matrix = torch.zeros(out, size, dtype=torch.float64)
    matrix.index_put_((rows, low), 1.0 - fraction, accumulate=True)
    matrix.index_put_((rows, (low + 1).clamp(max=size - 1)), fraction, accumulate=True)
    if smooth:
        taps = torch.tensor(FIELD_SMOOTHING, dtype=torch.float64) / sum(FIELD_SMOOTHING)
        half = len(FIELD_SMOOTHING) // 2
        smoothing = torch.zeros(out, out, dtype=torch.float64)
        for offset, tap in zip(range(-half, half + 1), taps, strict=True):
            smoothing.index_put_((rows, (rows + offset).clamp(0, out - 1)), tap, accumulate=True)
        matrix = smoothing @ matrix
    return matrix.float()
