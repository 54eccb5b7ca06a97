"""The one mapping between 8-bit pixels and unit floats."""

from __future__ import annotations

import torch

from camdegrade._support.pixels import bytes_to_unit, unit_to_bytes


def test_bytes_to_unit_divides_by_255():
    values = torch.arange(256, dtype=torch.uint8)
    unit = bytes_to_unit(values)
    assert unit.dtype == torch.float32
    assert torch.equal(unit, values.float() / 255.0)


def test_unit_to_bytes_rounds_half_to_even_and_clamps():
    levels = torch.tensor([-0.5, 0.0, 0.5, 1.5, 2.5, 127.49, 254.5, 255.0, 300.0]) / 255.0
    expected = torch.tensor([0, 0, 0, 2, 2, 127, 254, 255, 255], dtype=torch.uint8)
    assert torch.equal(unit_to_bytes(levels), expected)


def test_unit_to_bytes_matches_the_plain_cast_on_every_level():
    unit = torch.rand(3, 64, 64, generator=torch.Generator().manual_seed(0)) * 1.2 - 0.1
    reference = unit.mul(255.0).round().clamp(0, 255).to(torch.uint8)
    assert torch.equal(unit_to_bytes(unit), reference)
    kept = unit.clone()
    unit_to_bytes(unit)
    assert torch.equal(unit, kept)  # without overwrite the input is left alone
    unit_to_bytes(unit, overwrite=True)
    assert not torch.equal(unit, kept)
