"""Standard-normal fields: reproducible whatever the thread count, and safe in forked DataLoader workers."""

from __future__ import annotations

import pytest
import torch
from torch.utils.data import DataLoader, Dataset

from camdegrade._support import gaussian_fields as _random
from camdegrade._support.gaussian_fields import BLOCK, MIN_BLOCKS, standard_normal


@pytest.fixture
def two_threads():
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


def test_a_small_field_is_one_randn_call():
    shape = (1, 3, 64, 64)
    drawn = standard_normal(shape, torch.Generator().manual_seed(0))
    assert torch.equal(drawn, torch.randn(shape, generator=torch.Generator().manual_seed(0)))


def test_a_large_field_has_the_same_values_on_one_and_on_two_threads(two_threads):
    shape = (2, MIN_BLOCKS, BLOCK // 2 + 3)  # not a whole number of blocks
    torch.set_num_threads(1)
    one = standard_normal(shape, torch.Generator().manual_seed(7))
    torch.set_num_threads(2)
    two = standard_normal(shape, torch.Generator().manual_seed(7))
    assert one.shape == shape and one.dtype == torch.float32
    assert torch.equal(one, two)
    again = standard_normal(shape, torch.Generator().manual_seed(7))
    assert torch.equal(one, again)
    other = standard_normal(shape, torch.Generator().manual_seed(8))
    assert not torch.equal(one, other)


def test_a_large_field_is_standard_normal_and_its_blocks_are_independent(two_threads):
    torch.set_num_threads(2)
    field = standard_normal((MIN_BLOCKS * BLOCK,), torch.Generator().manual_seed(1))
    assert abs(float(field.mean())) < 0.005 and abs(float(field.std()) - 1.0) < 0.005
    blocks = field.view(MIN_BLOCKS, BLOCK)
    correlation = torch.corrcoef(blocks)
    off_diagonal = correlation[~torch.eye(MIN_BLOCKS, dtype=torch.bool)]
    assert float(off_diagonal.abs().max()) < 0.02  # 4 / sqrt(BLOCK) ≈ 0.016 at four sigma


def test_the_global_generator_is_used_without_one(two_threads):
    shape = (MIN_BLOCKS, BLOCK)
    torch.manual_seed(3)
    first = standard_normal(shape)
    torch.manual_seed(3)
    assert torch.equal(first, standard_normal(shape))


class _Fields(Dataset):
    def __len__(self) -> int:
        return 2

    def __getitem__(self, index: int) -> torch.Tensor:
        torch.set_num_threads(2)  # DataLoader workers start with one thread, which would not use the helpers
        return standard_normal((MIN_BLOCKS, BLOCK), torch.Generator().manual_seed(index))


def test_forked_workers_draw_with_their_own_threads(two_threads):
    torch.set_num_threads(2)
    standard_normal((MIN_BLOCKS, BLOCK))  # the parent now holds a helper thread; a fork does not copy it
    loader = DataLoader(_Fields(), batch_size=None, num_workers=1, multiprocessing_context="fork", timeout=30)
    drawn = list(loader)
    assert _random._pool is not None
    for index, field in enumerate(drawn):
        assert torch.equal(field, standard_normal((MIN_BLOCKS, BLOCK), torch.Generator().manual_seed(index)))
