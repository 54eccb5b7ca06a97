"""The local-affine network's CPU plan: :class:`~camdegrade.network.LocalAffineNet`'s arithmetic for inference."""

from __future__ import annotations

import functools

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade._onednn import FUSED_LINEAR, conv_relu, live_linear_relu, use_fused_kernels
from camdegrade._pixels import bytes_to_unit
from camdegrade.network import (
    FIELD_SMOOTHING,
    SIZE_MULTIPLE,
    LocalAffineNet,
    check_batch,
    piecewise_linear,
    smoothed,
)


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
      with its 3 outputs padded by zeros to :data:`FILTER_OUTPUTS`.
    - Images are computed one at a time, so each gets the same bytes alone as in any batch or chunk.

    Measured with 2 threads, one 224² photograph, the built-in ``city100-iphonex``'s network: on an AMD EPYC (Zen 3,
    AVX2) in float32 10.1 ms against the module's 17.9 ms on channels-last input (the paper network's plan of the
    same width: 7.3–8.1 ms); on a Xeon with AMX in bfloat16 3.7 ms (the paper network's plan: 2.4 ms), of which the
    float32 filter takes 1.4 ms and the field's upsampling 0.6 ms.

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
            weight, bias = network.linear.weight.detach(), network.linear.bias.detach()
            padded_weight = weight.new_zeros(FILTER_OUTPUTS, *weight.shape[1:])
            padded_weight[:3] = weight
            padded_bias = bias.new_zeros(FILTER_OUTPUTS)
            padded_bias[:3] = bias
            self.linear = (padded_weight.contiguous(memory_format=channels_last), padded_bias)

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
        return output

    def _input_curve(self, image: Tensor, unit: Tensor) -> Tensor:
        """``f(x)`` of one image (``unit`` itself without curves): a byte image by table lookup, the same values."""
        if self.curve is None:
            return unit
        if image.dtype == torch.uint8:
            offsets = torch.arange(0, 3 * 256, 256).view(1, 3, 1, 1)
            return torch.take(self._byte_curve, image.long().add_(offsets))
        return piecewise_linear(unit, self.curve[0])

    def _run_aligned(self, image: Tensor, curved: Tensor) -> Tensor:
        """``clamp(g(A(x) · (K ∗ f(x)) + b(x)), 0, 1)`` for one ``(1, 3, H, W)`` image with H and W multiples of 4
        and ``curved`` = ``f(image)`` (``f`` and ``g`` the network's curves, or none: ``curved`` is ``image``)."""
        hidden = image.to(self.dtype)
        for weight, bias in self.encode:
            hidden = conv_relu(hidden, weight, bias, self._fused)
        rows, cols = hidden.shape[-2:]
        pixels = hidden.permute(0, 2, 3, 1).reshape(rows * cols, -1)
        second, second_bias = self.decode[1]
        field = torch.addmm(second_bias, self._decode1(pixels), second.t()).float()
        field = upsampled_field(field.t().reshape(1, -1, rows, cols), self.smooth)
        half = self.linear[0].shape[-1] // 2
        padded = F.pad(curved, (half, half, half, half), mode="replicate").contiguous(memory_format=torch.channels_last)
        filtered = F.conv2d(padded, *self.linear)[:, :3].contiguous()
        out = filtered + field[:, 9:]
        for row in range(3):
            for column in range(3):
                out[:, row].addcmul_(field[:, 3 * row + column], filtered[:, column])
        if self.curve is not None:
            out = piecewise_linear(out, self.curve[1])
        return out.clamp_(0.0, 1.0)

    def _decode1(self, pixels: Tensor) -> Tensor:
        """ReLU of the first decoder product for one image's encoder ``pixels`` ``(M, C)``: in float32 without the
        channels that are zero over the image; in bfloat16 whole (a column gather costs more than it saves there:
        see :meth:`CpuInference._decode1`; 0.87 ms against 0.22 ms for a 224² image on a Xeon with AMX, 2 threads)."""
        weight, bias = self.decode[0]
        if self.dtype == torch.float32:
            return live_linear_relu(pixels, weight, bias)
        if self._fused:
            return FUSED_LINEAR(pixels.contiguous(), weight, bias, "relu", [], "")
        return torch.addmm(bias, pixels, weight.t()).relu_()


#: The local-affine plan's 7×7 filter computes this many outputs (3, then zeros): oneDNN's channels-last kernel is
#: faster with 8 than with 3 on an AMD EPYC Zen 3 (1.3–1.6 ms against 1.6–2.3 ms for a 224² image, 2 threads); on a
#: Xeon with AVX-512 both take 1.4 ms.
FILTER_OUTPUTS = 8


#: Fields of at most this many rows and columns (images up to 256²) are upsampled by two small matrix products;
#: larger ones by interpolation, whose cost grows with the pixels alone. For a 224² image's 12-channel field: 0.38 ms
#: against 0.96 ms on a Xeon with AMX, 0.82 against 0.94 on an AMD EPYC Zen 3; at 128 rows the interpolation is
#: already as fast (2 threads).
MATRIX_UPSAMPLING_MAX = 64


def byte_curve(knots: Tensor) -> Tensor:
    """The curve through ``knots`` ``(3, K)`` at every byte value, per channel, flattened ``(3 · 256,)``: exactly what
    :func:`~camdegrade.network.piecewise_linear` gives a byte image read as ``value / 255`` (the same arithmetic on
    the same floats), in a lookup of about half its time (0.55 against 0.97–1.27 ms for a 224² image, AMD EPYC Zen 3,
    2 threads)."""
    values = bytes_to_unit(torch.arange(256, dtype=torch.uint8)).expand(1, 3, 1, 256)
    return piecewise_linear(values, knots).reshape(-1)


def upsampled_field(field: Tensor, smooth: bool) -> Tensor:
    """The colour field ``(1, C, rows, cols)`` (contiguous) at full resolution, as :class:`LocalAffineNet` makes it:
    bilinear by :data:`~camdegrade.network.SIZE_MULTIPLE`, then with ``smooth`` its smoothing."""
    rows, cols = field.shape[-2:]
    if max(rows, cols) <= MATRIX_UPSAMPLING_MAX:
        down, across = upsampling_matrix(rows, smooth), upsampling_matrix(cols, smooth)
        return torch.matmul(down, torch.matmul(field[0], across.t()))[None]
    field = F.interpolate(field, scale_factor=SIZE_MULTIPLE, mode="bilinear", align_corners=False)
    return smoothed(field) if smooth else field


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
