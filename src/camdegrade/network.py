"""The domain-shifting network of Hegde et al., in true CHW layout, for any image size."""

from __future__ import annotations

import functools
import threading
import weakref
from typing import Any, Literal

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from camdegrade._fingerprint import module_tensors, tensors_fingerprint
from camdegrade._pixels import bytes_to_unit

#: Total down-sampling of the encoder; inputs are padded to a multiple of this.
SIZE_MULTIPLE = 4
#: How the network runs at inference: ``"float32"`` is the exact reference; ``"bfloat16"`` runs the convolutions in
#: bfloat16 (channels-last); ``"auto"`` picks bfloat16 where the device computes it natively, else float32.
Precision = Literal["auto", "float32", "bfloat16"]
PRECISIONS: tuple[str, ...] = ("auto", "float32", "bfloat16")


class DomainShiftNet(nn.Module):
    """The paper's clean → captured regression network.

    Conv 3→64 3×3 s2 p1, ReLU, Conv 64→128 3×3 s2 p1, ReLU, ConvT 128→64 2×2 s2, ReLU, ConvT 64→3 2×2 s2,
    sigmoid. No batch norm; 109,251 parameters.

    Any ``H×W ≥ 1`` is accepted: the image is padded at the bottom and right by replicating its last row and
    column up to the next multiple of 4, run through the network, and cropped back. Padding at the bottom/right
    keeps the network's 4-pixel grid anchored at the top-left corner, so a crop whose corner lies on that grid
    gives the same pixels as the full image would there (away from the padded border). Replicate padding works
    for every size, including 1×1, where reflect padding would not.

    Args:
        width: channels of the first conv layer (the paper: 64; the second layer has twice as many).

    Shape:
        - Input: ``(N, 3, H, W)``, float in ``[0, 1]``.
        - Output: ``(N, 3, H, W)``, float in ``(0, 1)``.

    Examples:
        >>> net = DomainShiftNet()
        >>> sum(p.numel() for p in net.parameters())
        109251
        >>> net(torch.rand(2, 3, 5, 7)).shape
        torch.Size([2, 3, 5, 7])
    """

    def __init__(self, width: int = 64) -> None:
        super().__init__()
        if not isinstance(width, int) or width < 1:
            raise ValueError(f"width must be a positive integer, got width={width!r}")
        self.width = width
        self.encode1 = nn.Conv2d(3, width, kernel_size=3, stride=2, padding=1)
        self.encode2 = nn.Conv2d(width, 2 * width, kernel_size=3, stride=2, padding=1)
        self.decode1 = nn.ConvTranspose2d(2 * width, width, kernel_size=2, stride=2)
        self.decode2 = nn.ConvTranspose2d(width, 3, kernel_size=2, stride=2)

    def config(self) -> dict[str, Any]:
        """JSON-serialisable arguments that rebuild this network's shape."""
        return {"width": self.width}

    def forward_aligned(self, image: Tensor) -> Tensor:
        """The bare network, for inputs whose H and W are already multiples of 4 (training crops)."""
        hidden = F.relu(self.encode1(image))
        hidden = F.relu(self.encode2(hidden))
        hidden = F.relu(self.decode1(hidden))
        return torch.sigmoid(self.decode2(hidden))

    def forward(self, image: Tensor) -> Tensor:
        if image.ndim != 4 or image.shape[1] != 3:
            raise ValueError(f"image must have shape (N, 3, H, W), got shape {tuple(image.shape)}")
        height, width = image.shape[-2:]
        pad_bottom = -height % SIZE_MULTIPLE
        pad_right = -width % SIZE_MULTIPLE
        if pad_bottom or pad_right:
            image = F.pad(image, (0, pad_right, 0, pad_bottom), mode="replicate")
        return self.forward_aligned(image)[..., :height, :width]


def native_bfloat16(device: torch.device) -> bool:
    """Whether ``device`` computes bfloat16 convolutions natively (CUDA with bf16, or a CPU with AVX-512 BF16/AMX)."""
    if device.type == "cuda":
        return torch.cuda.is_bf16_supported()
    if device.type == "cpu":
        return _cpu_native_bfloat16()
    return False


@functools.cache
def _cpu_native_bfloat16() -> bool:
    return bool(torch.backends.mkldnn.is_available() and torch.ops.mkldnn._is_mkldnn_bf16_supported())


def resolve_precision(precision: Precision, device: torch.device) -> str:
    """``"float32"`` or ``"bfloat16"``: the concrete precision for ``precision`` on ``device``."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {PRECISIONS}, got precision={precision!r}")
    if precision == "auto":
        return "bfloat16" if native_bfloat16(device) else "float32"
    return precision


def run_network(network: DomainShiftNet, image: Tensor, precision: Precision = "float32") -> Tensor:
    """The network's float32 output for ``image`` (float in [0, 1], or uint8 read as ``value / 255``), computed at
    ``precision`` (see :data:`Precision`).

    bfloat16 keeps 8-bit outputs within 1 level of float32 on ≥ 99.9 % of pixels of natural images (tested).
    On the CPU without autograd, bfloat16 runs :class:`BFloat16Inference` (fused convolutions, decoders as
    matrix products); elsewhere it runs the module under autocast.
    """
    concrete = resolve_precision(precision, image.device)
    if concrete == "bfloat16" and _plan_applies(network, image):
        return _cpu_inference(network).run(image)  # reads uint8 directly
    if image.dtype == torch.uint8:
        image = bytes_to_unit(image)
    if concrete == "float32":
        return network(image)
    with torch.autocast(image.device.type, dtype=torch.bfloat16):
        output = network(image.contiguous(memory_format=torch.channels_last))
    return output.float().contiguous()


def _plan_applies(network: DomainShiftNet, image: Tensor) -> bool:
    """Whether :class:`BFloat16Inference` can run: a CPU with native bfloat16, and no graph to build."""
    if image.device.type != "cpu" or not native_bfloat16(image.device):
        return False
    if not torch.is_grad_enabled():
        return True
    return not (image.requires_grad or any(parameter.requires_grad for parameter in module_tensors(network)))


_INFERENCE_CACHE: weakref.WeakKeyDictionary[DomainShiftNet, BFloat16Inference] = weakref.WeakKeyDictionary()
_INFERENCE_LOCK = threading.Lock()


def _cpu_inference(network: DomainShiftNet) -> BFloat16Inference:
    """The cached bfloat16 plan of ``network``, rebuilt whenever one of its parameters changes."""
    fingerprint = tensors_fingerprint(module_tensors(network))
    with _INFERENCE_LOCK:
        plan = _INFERENCE_CACHE.get(network)
        if plan is None or plan.fingerprint != fingerprint:
            plan = BFloat16Inference(network, fingerprint)
            _INFERENCE_CACHE[network] = plan
        return plan


class BFloat16Inference:
    """``DomainShiftNet`` for CPU inference in bfloat16, with the same arithmetic as the module up to rounding.

    The encoder runs as channels-last oneDNN convolutions with the ReLU fused in. Each 2×2/stride-2 transposed
    convolution maps every input pixel to its own 2×2 output block, so both decoders together are two matrix
    products per pixel of the encoder output: ``128 → (2·2·64)`` then, block-diagonally, ``(2·2·64) → (4·4·3)``.
    The second product's columns are ordered so that one strided copy lays the blocks out as an image; this
    replaces the transposed convolutions and pixel shuffles, the slowest part of the module on the CPU.
    """

    def __init__(self, network: DomainShiftNet, fingerprint: tuple[int, ...] = ()) -> None:
        self.fingerprint = fingerprint
        dtype, channels_last = torch.bfloat16, torch.channels_last
        with torch.no_grad():
            self.encode = [
                (conv.weight.to(dtype).contiguous(memory_format=channels_last), conv.bias.to(dtype))
                for conv in (network.encode1, network.encode2)
            ]
            # uint8 images enter as their byte values (exact in bfloat16); the first layer divides by 255.
            bytes_weight = network.encode1.weight / 255.0
            self.encode1_bytes_weight = bytes_weight.to(dtype).contiguous(memory_format=channels_last)
            first, second = network.decode1, network.decode2
            hidden, width = first.weight.shape[:2]
            # first.weight is (in, out, dy, dx); the first product's outputs are ordered (dy, dx, c).
            # (out, in) = ((dy, dx, c), in), the layout of a linear layer's weight.
            self.decode1_weight = first.weight.permute(2, 3, 1, 0).reshape(4 * width, hidden).to(dtype).contiguous()
            self.decode1_bias = first.bias.repeat(4).to(dtype)
            # Rows (dy, dx, c), columns (k, dy, ey, dx, ex): channel k, output row 4i + 2dy + ey, column 4j + 2dx + ex.
            blocks = torch.zeros(2, 2, width, 3, 2, 2, 2, 2)
            for dy in range(2):
                for dx in range(2):
                    blocks[dy, dx, :, :, dy, :, dx, :] = second.weight
            self.decode2_weight = blocks.reshape(4 * width, 48).to(dtype)
            self.decode2_bias = second.bias.repeat_interleave(16).to(dtype)

    def run(self, image: Tensor) -> Tensor:
        """``(N, 3, H, W)`` float in [0, 1] or uint8 → the network's float32 output, contiguous, same shape."""
        if image.ndim != 4 or image.shape[1] != 3:
            raise ValueError(f"image must have shape (N, 3, H, W), got shape {tuple(image.shape)}")
        n, _, height, width = image.shape
        pad_bottom, pad_right = -height % SIZE_MULTIPLE, -width % SIZE_MULTIPLE
        rows, cols = (height + pad_bottom) // 4, (width + pad_right) // 4
        with torch.no_grad():
            # Plain NCHW in: oneDNN's first convolution reads it faster than a channels-last copy can be made.
            hidden = image.to(torch.bfloat16)
            if pad_bottom or pad_right:
                hidden = F.pad(hidden, (0, pad_right, 0, pad_bottom), mode="replicate")
            (weight, bias), second = self.encode
            if image.dtype == torch.uint8:
                weight = self.encode1_bytes_weight
            hidden = _conv_relu(_conv_relu(hidden, weight, bias), *second)
            pixels = hidden.permute(0, 2, 3, 1).reshape(n * rows * cols, -1)
            blocks = _linear_relu(pixels, self.decode1_weight, self.decode1_bias)
            blocks = torch.addmm(self.decode2_bias, blocks, self.decode2_weight).float()
            output = torch.empty(n, 3, 4 * rows, 4 * cols)
            output.view(n, 3, rows, 4, cols, 4).copy_(blocks.view(n, rows, cols, 3, 4, 4).permute(0, 3, 1, 4, 2, 5))
            output.sigmoid_()
            if pad_bottom or pad_right:
                output = output[..., :height, :width].contiguous()
            return output


def _conv_relu(image: Tensor, weight: Tensor, bias: Tensor) -> Tensor:
    """ReLU(conv 3×3, stride 2, padding 1), through oneDNN's fused kernel where this build has it."""
    if _FUSED_CONV is not None:
        return _FUSED_CONV(image, weight, bias, [1, 1], [2, 2], [1, 1], 1, "relu", [], "")
    return F.conv2d(image, weight, bias, stride=2, padding=1).relu_()


def _linear_relu(rows: Tensor, weight: Tensor, bias: Tensor) -> Tensor:
    """ReLU(rows @ weightᵀ + bias), through oneDNN's fused kernel where this build has it."""
    if _FUSED_LINEAR is not None:
        return _FUSED_LINEAR(rows, weight, bias, "relu", [], "")
    return torch.addmm(bias, rows, weight.t()).relu_()


def _onednn_op(name: str) -> Any:
    """One of oneDNN's fused CPU kernels (private torch ops that torch.compile uses), or None without them."""
    if not torch.backends.mkldnn.is_available():
        return None
    return getattr(torch.ops.mkldnn, name, None)


_FUSED_CONV = _onednn_op("_convolution_pointwise")
_FUSED_LINEAR = _onednn_op("_linear_pointwise")
