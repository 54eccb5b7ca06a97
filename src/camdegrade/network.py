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
#: ``"smooth"``: bilinear, then :data:`FIELD_SMOOTHING` along each axis. Not the default: on City100 with the fast
#: recipe its fit stopped at the linear baseline's validation PSNR (29.59 dB at epoch 1 of 5, held-out 29.86 dB)
#: where the bilinear field's reached 30.39 dB (held-out 30.72 dB; docs/fitting.md). Profiles written before this
#: choice existed hold no ``upsample`` key and load as ``"bilinear"``.
FIELD_UPSAMPLING = ("bilinear", "smooth")
#: ``[1 2 2 2 1] / 8`` = a 4-tap box convolved with a 2-tap box: it keeps a constant field exactly, puts zeros at
#: 1/4 and 1/2 cycles/pixel (the period-4 harmonics), and after bilinear upsampling (itself two 4-tap boxes and a
#: 2-tap box on the zero-filled field) makes the field a smooth spline of its quarter-resolution samples.
FIELD_SMOOTHING = (1.0, 2.0, 2.0, 2.0, 1.0)


class LocalAffineNet(ShiftNetwork):
    """A network without a fixed-pattern grid (``arch="local_affine"``), camdegrade's default.

    ``output = clamp(A(x) · (K ∗ x) + b(x), 0, 1)``: ``K`` is a full-resolution 7×7 linear colour filter (the
    camera's PSF, sharpening and global colour map, all linear), and ``A`` (3×3, around the identity) and ``b`` are a
    per-pixel colour transform predicted by the paper's encoder at a quarter of the resolution (two 1×1
    convolutions, 2w → w → 12) and upsampled (bilinearly, or to a smoother spline: ``upsample``), so they vary
    smoothly over the frame: local tone, contrast and colour. Fine detail reaches the output through ``K`` at full
    resolution, never through a stride-2 decoder, so nothing repeats every 4 pixels; the transform is smooth, so a
    tone curve is followed locally.

    Initialised to pass the image through (``K`` the identity, ``A`` the identity, ``b`` zero); a fit starts it
    from a least-squares linear baseline (:func:`camdegrade.fitting.baseline.fit_linear_baseline`). About the
    paper network's arithmetic per pixel (its encoder dominates both).

    Args:
        width: channels of the first conv layer, as :class:`DomainShiftNet`'s.
        upsample: how the colour field reaches full resolution, one of :data:`FIELD_UPSAMPLING` (``"bilinear"``,
            the default and what older profiles hold, or ``"smooth"``, whose slope does not change every 4 pixels).

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

    def __init__(self, width: int = 64, upsample: str = "bilinear") -> None:
        super().__init__(width)
        if upsample not in FIELD_UPSAMPLING:
            raise ValueError(f"upsample must be one of {FIELD_UPSAMPLING}, got upsample={upsample!r}")
        self.upsample = upsample
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
        return super().config() | {"upsample": self.upsample}

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
        filtered = self.filtered(image)
        field = self.colour_field(image)
        n, _, height, width = filtered.shape
        matrix = field[:, :9].reshape(n, 3, 3, height, width)
        mixed = filtered + (matrix * filtered[:, None]).sum(dim=2)
        return (mixed + field[:, 9:]).clamp(0.0, 1.0)


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


def build_network(arch: str = "paper", width: int = 64, upsample: str = "bilinear") -> ShiftNetwork:
    """A fresh network of architecture ``arch`` (a key of :data:`ARCHITECTURES`) and ``width``; ``upsample`` (one of
    :data:`FIELD_UPSAMPLING`) is :class:`LocalAffineNet`'s, which the paper network has no use for."""
    if arch not in ARCHITECTURES:
        raise ValueError(f"arch must be one of {tuple(ARCHITECTURES)}, got arch={arch!r}")
    if ARCHITECTURES[arch] is LocalAffineNet:
        return LocalAffineNet(width, upsample)
    if upsample not in FIELD_UPSAMPLING:
        raise ValueError(f"upsample must be one of {FIELD_UPSAMPLING}, got upsample={upsample!r}")
    return ARCHITECTURES[arch](width)
