"""DomainShiftNet: the paper's architecture, in CHW layout, for every image size."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from torch import nn

from camdegrade import DomainShiftNet
from profiles_for_tests import seeded_network


def test_parameter_count_matches_the_paper():
    assert sum(p.numel() for p in DomainShiftNet().parameters()) == 109_251


def test_layers_are_the_papers():
    net = DomainShiftNet()
    layers = [m for m in net.modules() if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d))]
    shapes = [(type(m).__name__, m.in_channels, m.out_channels, m.kernel_size, m.stride, m.padding) for m in layers]
    assert shapes == [
        ("Conv2d", 3, 64, (3, 3), (2, 2), (1, 1)),
        ("Conv2d", 64, 128, (3, 3), (2, 2), (1, 1)),
        ("ConvTranspose2d", 128, 64, (2, 2), (2, 2), (0, 0)),
        ("ConvTranspose2d", 64, 3, (2, 2), (2, 2), (0, 0)),
    ]
    assert not any(isinstance(m, nn.modules.batchnorm._BatchNorm) for m in net.modules())


@pytest.mark.parametrize("size", range(1, 68))
def test_square_sizes_1_to_67_keep_their_size(size):
    out = seeded_network()(torch.rand(1, 3, size, size))
    assert out.shape == (1, 3, size, size)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(height=st.integers(1, 67), width=st.integers(1, 67), batch=st.integers(1, 3))
def test_any_size_keeps_its_size(height, width, batch):
    with torch.no_grad():
        out = seeded_network()(torch.rand(batch, 3, height, width))
    assert out.shape == (batch, 3, height, width)
    assert float(out.min()) > 0.0 and float(out.max()) < 1.0


def test_layout_is_channels_first():
    """Each output pixel depends on its own neighbourhood: changing one corner never moves the far corner.

    The paper's code reshaped HWC buffers as CHW, which mixes rows and channels; this checks that we do not."""
    net = seeded_network()
    image = torch.rand(1, 3, 32, 32)
    changed = image.clone()
    changed[..., :4, :4] = 1 - changed[..., :4, :4]
    with torch.no_grad():
        diff = (net(image) - net(changed)).abs()
    assert float(diff[..., :4, :4].max()) > 0
    assert float(diff[..., 8:, 8:].max()) == 0


def test_crop_on_the_grid_matches_the_full_image_away_from_borders():
    net = seeded_network()
    image = torch.rand(1, 3, 40, 40)
    with torch.no_grad():
        full = net(image)
        crop = net(image[..., 8:32, 12:36])
    assert torch.allclose(full[..., 12:28, 16:32], crop[..., 4:20, 4:20], atol=1e-6)


def test_bad_input_shape():
    with pytest.raises(ValueError, match=r"\(N, 3, H, W\), got shape \(3, 8, 8\)"):
        DomainShiftNet()(torch.rand(3, 8, 8))


def test_bad_width():
    with pytest.raises(ValueError, match="width must be an integer from 1 to 1024, got width=0"):
        DomainShiftNet(width=0)
