"""The domain-shifting network of Hegde et al., in true CHW layout, for any image size."""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

#: Total down-sampling of the encoder; inputs are padded to a multiple of this.
SIZE_MULTIPLE = 4
#: The widest network built (the paper's is 64): 1024 channels are 27 M parameters, 110 MB. A profile's metadata
#: names the width, so this bounds what a file can make camdegrade allocate.
MAX_WIDTH = 1024


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
        width: channels of the first conv layer (the paper: 64; the second layer has twice as many), at most
            :data:`MAX_WIDTH`.

    References:
        G. Hegde et al., "A Simple Domain Shifting Network for Generating Low Quality Images", arXiv, June 2020.

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
        if isinstance(width, bool) or not isinstance(width, int) or not 1 <= width <= MAX_WIDTH:
            raise ValueError(f"width must be an integer from 1 to {MAX_WIDTH}, got width={width!r}")
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
