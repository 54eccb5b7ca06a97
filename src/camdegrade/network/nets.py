"""The networks that map clean → captured, in true CHW layout, for any image size.

Two architectures share one encoder (the paper's two stride-2 convolutions) and differ in how they return to full
resolution: :class:`DomainShiftNet` is the paper's (two 2×2 stride-2 transposed convolutions), kept exactly for
reproduction; :class:`LocalAffineNet` predicts a smooth field of per-pixel colour transforms and applies it to a
full-resolution linear filter of the image, which prints no period. :data:`ARCHITECTURES` names them as profiles,
recipes and the command line do.
"""

from __future__ import annotations

from typing import Any, ClassVar

import torch
import torch.nn.functional as F
from torch import Tensor, nn

__all__ = [
    "ARCHITECTURES",
    "CURVE_KNOTS",
    "FIELD_CHANNELS",
    "FIELD_SMOOTHING",
    "FIELD_UPSAMPLING",
    "LINEAR_TAPS",
    "MAX_WIDTH",
    "SIZE_MULTIPLE",
    "DomainShiftNet",
    "LocalAffineNet",
    "ShiftNetwork",
    "build_network",
    "check_batch",
    "piecewise_linear",
    "smoothed",
]

#: Total down-sampling of the encoder; inputs are padded to a multiple of this.
SIZE_MULTIPLE = 4
#: The widest network built (the paper's is 64): 1024 channels are 27 M parameters, 110 MB. A profile's metadata
#: names the width, so this bounds what a file can make camdegrade allocate.
MAX_WIDTH = 1024


class ShiftNetwork(nn.Module):
    """What both architectures share: the paper's encoder (Conv 3→w 3×3 s2 p1, ReLU, Conv w→2w 3×3 s2 p1, ReLU), the
    width check, the config a profile records, and padding any ``H×W ≥ 1`` to a multiple of 4.

    The image is padded at the bottom and right by replicating its last row and column up to the next multiple of 4,
    run through the network, and cropped back. Padding at the bottom/right keeps the encoder's 4-pixel lattice
    anchored at the top-left corner, so a crop whose corner lies on it gives the same pixels as the full image would
    there (away from the padded border). Replicate padding works for every size, including 1×1.

    Shape:
        - Input: ``(N, 3, H, W)``, float in ``[0, 1]``.
        - Output: ``(N, 3, H, W)``, float in ``[0, 1]``.
    """

    #: The name profiles, recipes and the command line use (``--arch``).
    arch: ClassVar[str] = ""

    def __init__(self, width: int = 64) -> None:
        super().__init__()
        if isinstance(width, bool) or not isinstance(width, int) or not 1 <= width <= MAX_WIDTH:
            raise ValueError(f"width must be an integer from 1 to {MAX_WIDTH}, got width={width!r}")
        self.width = width
        self.encode1 = nn.Conv2d(3, width, kernel_size=3, stride=2, padding=1)
        self.encode2 = nn.Conv2d(width, 2 * width, kernel_size=3, stride=2, padding=1)

    def config(self) -> dict[str, Any]:
        """JSON-serialisable arguments that rebuild this network's shape."""
        return {"width": self.width}

    def encode(self, image: Tensor) -> Tensor:
        """The ``2·width`` features at a quarter of the resolution."""
        return F.relu(self.encode2(F.relu(self.encode1(image))))

    def forward_aligned(self, image: Tensor) -> Tensor:
        """The bare network, for inputs whose H and W are already multiples of 4 (training crops)."""
        raise NotImplementedError

    def forward(self, image: Tensor) -> Tensor:
        check_batch(image)
        height, width = image.shape[-2:]
        pad_bottom = -height % SIZE_MULTIPLE
        pad_right = -width % SIZE_MULTIPLE
        if pad_bottom or pad_right:
            image = F.pad(image, (0, pad_right, 0, pad_bottom), mode="replicate")
        return self.forward_aligned(image)[..., :height, :width]


class DomainShiftNet(ShiftNetwork):
    """The paper's clean → captured regression network (``arch="paper"``).

    Conv 3→64 3×3 s2 p1, ReLU, Conv 64→128 3×3 s2 p1, ReLU, ConvT 128→64 2×2 s2, ReLU, ConvT 64→3 2×2 s2,
    sigmoid. No batch norm; 109,251 parameters. Each 2×2 stride-2 transposed convolution writes every output pixel
    from its own kernel tap, so the output carries a 4-pixel period (Odena et al.); :class:`LocalAffineNet` does not.

    Args:
        width: channels of the first conv layer (the paper: 64; the second layer has twice as many), at most
            :data:`MAX_WIDTH`.

    References:
        G. Hegde et al., "A Simple Domain Shifting Network for Generating Low Quality Images", arXiv, June 2020;
        A. Odena, V. Dumoulin, C. Olah, "Deconvolution and Checkerboard Artifacts", Distill, 2016.

    Examples:
        >>> net = DomainShiftNet()
        >>> sum(p.numel() for p in net.parameters())
        109251
        >>> net(torch.rand(2, 3, 5, 7)).shape
        torch.Size([2, 3, 5, 7])
    """

    arch = "paper"

    def __init__(self, width: int = 64) -> None:
        super().__init__(width)
        self.decode1 = nn.ConvTranspose2d(2 * width, width, kernel_size=2, stride=2)
        self.decode2 = nn.ConvTranspose2d(width, 3, kernel_size=2, stride=2)

    def forward_aligned(self, image: Tensor) -> Tensor:
        hidden = F.relu(self.decode1(self.encode(image)))
        return torch.sigmoid(self.decode2(hidden))


#: Taps of :class:`LocalAffineNet`'s full-resolution linear filter: room for a Gaussian PSF of σ up to about 1.5 px.
LINEAR_TAPS = 7
#: Channels of the per-pixel colour transform: a 3×3 matrix added to the identity, and an offset.
FIELD_CHANNELS = 12
#: How :class:`LocalAffineNet` brings its quarter-resolution colour field to full resolution. ``"bilinear"`` (the
#: default): a bilinear field changes slope every 4 pixels, which a trained network can print as a faint grid;
#: ``"smooth"``: bilinear, then :data:`FIELD_SMOOTHING` along each axis. Not the default: with the fast recipe its
#: fits have stopped early at a lower PSNR than the bilinear field's (docs/results.md, *The two networks, the colour
#: field and the pointwise curves*). Profiles written before this choice existed hold no ``upsample`` key and load
#: as ``"bilinear"``.
FIELD_UPSAMPLING = ("bilinear", "smooth")
#: ``[1 2 2 2 1] / 8`` = a 4-tap box convolved with a 2-tap box: it keeps a constant field exactly, puts zeros at
#: 1/4 and 1/2 cycles/pixel (the period-4 harmonics), and after bilinear upsampling (itself two 4-tap boxes and a
#: 2-tap box on the zero-filled field) makes the field a smooth spline of its quarter-resolution samples.
FIELD_SMOOTHING = (1.0, 2.0, 2.0, 2.0, 1.0)
#: Knots of :class:`LocalAffineNet`'s optional per-channel curves (``curves=True``), evenly spaced on [0, 1].
CURVE_KNOTS = 17


class LocalAffineNet(ShiftNetwork):
    """A network without a fixed-pattern grid (``arch="local_affine"``), camdegrade's default.

    ``output = clamp(A(x) · (K ∗ x) + b(x), 0, 1)``: ``K`` is a full-resolution 7×7 linear colour filter (the
    camera's PSF, sharpening and global colour map, all linear), and ``A`` (3×3, around the identity) and ``b`` are a
    per-pixel colour transform predicted by the paper's encoder at a quarter of the resolution (two 1×1
    convolutions, 2w → w → 12) and upsampled (bilinearly, or to a smoother spline: ``upsample``), so they vary
    smoothly over the frame: local tone, contrast and colour. Fine detail reaches the output through ``K`` at full
    resolution, never through a stride-2 decoder, so nothing repeats every 4 pixels; the transform is smooth, so a
    tone curve is followed locally.

    With ``curves=True``: ``output = clamp(g(A(x) · (K ∗ f(x)) + b(x)), 0, 1)``, where ``f`` and ``g`` are learned
    pointwise curves, one per channel (piecewise linear through :data:`CURVE_KNOTS` values, the identity at first).
    A camera's lens blurs linear light and its tone curve follows: ``f`` can decode, ``K`` blur, ``g`` apply the tone
    curve, at every pixel, where the smooth field alone bends its transform across an edge at a quarter of the
    resolution and prints that every 4 pixels (measured with and without the curves: docs/results.md, *The two
    networks, the colour field and the pointwise curves*).

    Initialised to pass the image through (``K`` the identity, ``A`` the identity, ``b`` zero); a fit starts it
    from a least-squares linear baseline (:func:`camdegrade.fitting.network.baseline.fit_linear_baseline`). About the
    paper network's arithmetic per pixel (its encoder dominates both).

    Args:
        width: channels of the first conv layer, as :class:`DomainShiftNet`'s.
        upsample: how the colour field reaches full resolution, one of :data:`FIELD_UPSAMPLING` (``"bilinear"``,
            the default and what older profiles hold, or ``"smooth"``, whose slope does not change every 4 pixels).
        curves: whether to learn the curves ``f`` and ``g`` (the fast recipe's default; profiles written before
            they existed hold none and load without them).

    References:
        M. Gharbi, J. Chen, J. T. Barron, S. W. Hasinoff, F. Durand, "Deep Bilateral Learning for Real-Time Image
        Enhancement", SIGGRAPH 2017 (per-pixel affine colour transforms predicted at low resolution; here a smooth
        smooth field stands in for their bilateral grid).

    Examples:
        >>> net = LocalAffineNet()
        >>> image = torch.rand(1, 3, 9, 10)
        >>> bool(torch.allclose(net(image), image))
        True
    """

    arch = "local_affine"

    def __init__(self, width: int = 64, upsample: str = "bilinear", curves: bool = False) -> None:
        super().__init__(width)
        if upsample not in FIELD_UPSAMPLING:
            raise ValueError(f"upsample must be one of {FIELD_UPSAMPLING}, got upsample={upsample!r}")
        if not isinstance(curves, bool):
            raise ValueError(f"curves must be True or False, got curves={curves!r}")
        self.upsample = upsample
        self.curves = curves
        if curves:
            # rows: the input curve (before K, per input channel) and the output curve (after the colour transform)
            self.curve = nn.Parameter(torch.linspace(0.0, 1.0, CURVE_KNOTS).repeat(2, 3, 1))
        self.linear = nn.Conv2d(3, 3, kernel_size=LINEAR_TAPS)
        self.decode1 = nn.Conv2d(2 * width, width, kernel_size=1)
        self.decode2 = nn.Conv2d(width, FIELD_CHANNELS, kernel_size=1)
        with torch.no_grad():
            self.linear.weight.zero_()
            self.linear.weight[:, :, LINEAR_TAPS // 2, LINEAR_TAPS // 2] = torch.eye(3)
            self.linear.bias.zero_()
            self.decode2.weight.zero_()
            self.decode2.bias.zero_()

    def config(self) -> dict[str, Any]:
        return super().config() | {"upsample": self.upsample} | ({"curves": True} if self.curves else {})

    def filtered(self, image: Tensor) -> Tensor:
        """``K ∗ x``, with the border replicated so that edges are not darkened."""
        half = LINEAR_TAPS // 2
        return self.linear(F.pad(image, (half, half, half, half), mode="replicate"))

    def colour_field(self, image: Tensor) -> Tensor:
        """The per-pixel transform ``(N, 12, H, W)``: 9 matrix entries (added to the identity), then 3 offsets."""
        field = self.decode2(F.relu(self.decode1(self.encode(image))))
        field = F.interpolate(field, scale_factor=SIZE_MULTIPLE, mode="bilinear", align_corners=False)
        return smoothed(field) if self.upsample == "smooth" else field

    def forward_aligned(self, image: Tensor) -> Tensor:
        filtered = self.filtered(piecewise_linear(image, self.curve[0]) if self.curves else image)
        field = self.colour_field(image)
        n, _, height, width = filtered.shape
        matrix = field[:, :9].reshape(n, 3, 3, height, width)
        mixed = filtered + (matrix * filtered[:, None]).sum(dim=2)
        out = mixed + field[:, 9:]
        if self.curves:
            out = piecewise_linear(out, self.curve[1])
        return out.clamp(0.0, 1.0)


def piecewise_linear(image: Tensor, knots: Tensor) -> Tensor:
    """Each channel ``c`` of ``image`` ``(N, C, H, W)`` through the curve through ``knots[c]`` ``(C, K)``, the values
    at ``K`` evenly spaced points of [0, 1]; inputs outside [0, 1] take the end values. Differentiable in both, with
    gradients summed in a fixed order (same seed, same bytes: a gather's own backward adds them in any order)."""
    if torch.is_grad_enabled() and (image.requires_grad or knots.requires_grad):
        return _PiecewiseLinear.apply(image, knots)
    _, weight, low, high = _segments(image, knots)
    return high.sub_(low).mul_(weight).add_(low)  # low + weight · (high − low), as the autograd path computes it


def _segments(image: Tensor, knots: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Per value of ``image``: its segment's index into ``knots`` flattened, its place in the segment (0 to 1), and
    the knot values at the segment's two ends."""
    segments = knots.shape[-1] - 1
    position = image.clamp(0.0, 1.0).mul_(segments)
    index = position.floor().clamp_(max=segments - 1)
    weight = position.sub_(index)
    flat = index.long() + (torch.arange(image.shape[1], device=image.device) * (segments + 1)).view(1, -1, 1, 1)
    table = knots.reshape(-1)
    return flat, weight, torch.take(table, flat), torch.take(table, flat + 1)


class _PiecewiseLinear(torch.autograd.Function):
    @staticmethod
    def forward(ctx: Any, image: Tensor, knots: Tensor) -> Tensor:
        flat, weight, low, high = _segments(image, knots)
        inside = (image >= 0.0) & (image <= 1.0)
        ctx.save_for_backward(flat, weight, (high - low) * (knots.shape[-1] - 1) * inside)
        ctx.knots_shape = knots.shape
        return low + weight * (high - low)

    @staticmethod
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor | None, Tensor | None]:
        flat, weight, slope = ctx.saved_tensors
        grad_image = grad * slope if ctx.needs_input_grad[0] else None
        grad_knots = None
        if ctx.needs_input_grad[1]:
            indices, share = flat.reshape(-1), (grad * weight).reshape(-1)
            size = ctx.knots_shape.numel()
            low = torch.bincount(indices, weights=grad.reshape(-1) - share, minlength=size)
            high = torch.bincount(indices + 1, weights=share, minlength=size)
            grad_knots = (low + high).to(grad.dtype).reshape(ctx.knots_shape)
        return grad_image, grad_knots


def smoothed(field: Tensor) -> Tensor:
    """``field`` filtered by :data:`FIELD_SMOOTHING` along each axis, each channel alone, the border replicated."""
    channels = field.shape[1]
    taps = field.new_tensor(FIELD_SMOOTHING) / sum(FIELD_SMOOTHING)
    half = len(FIELD_SMOOTHING) // 2
    padded = F.pad(field, (half, half, half, half), mode="replicate")
    across = F.conv2d(padded, taps.view(1, 1, 1, -1).expand(channels, 1, 1, -1), groups=channels)
    return F.conv2d(across, taps.view(1, 1, -1, 1).expand(channels, 1, -1, 1), groups=channels)


def check_batch(image: Tensor) -> None:
    """Refuse anything but an ``(N, 3, H, W)`` batch, what every network and its CPU plans take."""
    if image.ndim != 4 or image.shape[1] != 3:
        raise ValueError(f"image must have shape (N, 3, H, W), got shape {tuple(image.shape)}")


#: arch name → class, as profiles, recipes and ``--arch`` name them.
ARCHITECTURES: dict[str, type[ShiftNetwork]] = {cls.arch: cls for cls in (DomainShiftNet, LocalAffineNet)}


def build_network(
    arch: str = "paper", width: int = 64, upsample: str = "bilinear", *, curves: bool = False
) -> ShiftNetwork:
    """A fresh network of architecture ``arch`` (a key of :data:`ARCHITECTURES`) and ``width``; ``upsample`` (one of
    :data:`FIELD_UPSAMPLING`) and ``curves`` are :class:`LocalAffineNet`'s, which the paper network has no use for."""
    if arch not in ARCHITECTURES:
        raise ValueError(f"arch must be one of {tuple(ARCHITECTURES)}, got arch={arch!r}")
    if ARCHITECTURES[arch] is LocalAffineNet:
        return LocalAffineNet(width, upsample, curves)
    if upsample not in FIELD_UPSAMPLING:
        raise ValueError(f"upsample must be one of {FIELD_UPSAMPLING}, got upsample={upsample!r}")
    return ARCHITECTURES[arch](width)
