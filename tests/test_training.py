"""The network trainer: learns, is deterministic, checkpoints atomically, resumes exactly, survives Ctrl-C."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from camdegrade.fitting.checkpoint import load_checkpoint
from camdegrade.fitting.training import EpochResult, FitConfig, FitInterrupted, evaluate_psnr, fit_network

TINY = FitConfig(epochs=4, crop=16, batch_size=4, crops_per_pair=4, lr=0.01, seed=0)


def synthetic_pairs(count: int = 4, size: int = 24, seed: int = 0):
    """Captured = clean darkened and box-blurred: a degradation the network can learn."""
    generator = torch.Generator().manual_seed(seed)
    clean = torch.rand(count, 3, size, size, generator=generator)
    captured = F.avg_pool2d(clean * 0.7 + 0.1, 3, stride=1, padding=1, count_include_pad=False)
    to_uint8 = lambda t: (t * 255).round().to(torch.uint8)  # noqa: E731
    return [(to_uint8(c), to_uint8(r)) for c, r in zip(clean, captured)]


def weights_bytes(network) -> bytes:
    return b"".join(v.numpy().tobytes() for v in network.state_dict().values())


def test_training_improves_over_the_first_epoch():
    pairs = synthetic_pairs()
    network, history = fit_network(pairs[:3], pairs[3:], FitConfig(epochs=6, crop=16, batch_size=4, crops_per_pair=8))
    assert len(history) == 6 and history[-1].train_loss < history[0].train_loss
    assert evaluate_psnr(network, pairs[3:]) == pytest.approx(max(r.val_psnr for r in history), abs=1e-4)


def test_same_seed_same_weights_and_different_seed_differs():
    pairs = synthetic_pairs()
    first, _ = fit_network(pairs[:3], pairs[3:], TINY)
    second, _ = fit_network(pairs[:3], pairs[3:], TINY)
    other, _ = fit_network(pairs[:3], pairs[3:], FitConfig(**{**TINY.as_dict(), "seed": 1}))
    assert weights_bytes(first) == weights_bytes(second)
    assert weights_bytes(first) != weights_bytes(other)


def test_resume_continues_exactly(tmp_path):
    pairs = synthetic_pairs()
    straight, straight_history = fit_network(pairs[:3], pairs[3:], TINY)
    checkpoint = tmp_path / "fit.ckpt.safetensors"
    half = FitConfig(**{**TINY.as_dict(), "epochs": 2})
    fit_network(pairs[:3], pairs[3:], half, checkpoint=checkpoint)
    assert load_checkpoint(checkpoint).epoch == 2
    resumed, history = fit_network(pairs[:3], pairs[3:], TINY, checkpoint=checkpoint, resume=True)
    assert [r.epoch for r in history] == [1, 2, 3, 4]
    assert [r.train_loss for r in history] == [r.train_loss for r in straight_history]
    assert weights_bytes(resumed) == weights_bytes(straight)


def test_ctrl_c_keeps_the_last_finished_epoch(tmp_path):
    pairs = synthetic_pairs()
    checkpoint = tmp_path / "fit.ckpt.safetensors"

    def interrupt_after_two(result: EpochResult) -> None:
        if result.epoch == 2:
            raise KeyboardInterrupt

    with pytest.raises(FitInterrupted, match=r"after epoch 2 of 4.*resume"):
        fit_network(pairs[:3], pairs[3:], TINY, checkpoint=checkpoint, callback=interrupt_after_two)
    assert load_checkpoint(checkpoint).epoch == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fit.ckpt.safetensors"]  # no temp files left
    resumed, _ = fit_network(pairs[:3], pairs[3:], TINY, checkpoint=checkpoint, resume=True)
    straight, _ = fit_network(pairs[:3], pairs[3:], TINY)
    assert weights_bytes(resumed) == weights_bytes(straight)


def test_resume_refuses_a_different_recipe(tmp_path):
    pairs = synthetic_pairs()
    checkpoint = tmp_path / "fit.ckpt.safetensors"
    fit_network(pairs[:3], [], FitConfig(**{**TINY.as_dict(), "epochs": 1}), checkpoint=checkpoint)
    with pytest.raises(ValueError, match="different recipe"):
        fit_network(pairs[:3], [], FitConfig(**{**TINY.as_dict(), "lr": 0.001}), checkpoint=checkpoint, resume=True)


def test_callback_sees_every_epoch():
    seen = []
    fit_network(
        synthetic_pairs()[:2], [], FitConfig(epochs=3, crop=16, batch_size=4, crops_per_pair=2), callback=seen.append
    )
    assert [r.epoch for r in seen] == [1, 2, 3] and all(r.lr == 0.01 for r in seen)


def test_learning_rate_halves_every_30_epochs_by_default():
    seen = []
    config = FitConfig(epochs=31, crop=16, batch_size=8, crops_per_pair=1, lr_halving_epochs=30)
    fit_network(synthetic_pairs(2, 16), [], config, callback=seen.append)
    assert seen[29].lr == pytest.approx(0.01) and seen[30].lr == pytest.approx(0.005)


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("epochs", 0, "epochs must be a positive integer, got epochs=0"),
        ("crop", 30, "crop must be a multiple of 4, got crop=30"),
        ("lr", -1.0, "lr must be a positive number, got lr=-1.0"),
        ("batch_size", 2.5, "batch_size must be a positive integer"),
    ],
)
def test_config_errors(field, value, message):
    with pytest.raises(ValueError, match=message):
        FitConfig(**{field: value})


def test_pairs_errors():
    with pytest.raises(ValueError, match="at least one"):
        fit_network([], [], TINY)
    small = [(torch.zeros(3, 8, 8, dtype=torch.uint8), torch.zeros(3, 8, 8, dtype=torch.uint8))]
    with pytest.raises(ValueError, match=r"pair 0: image \(8, 8\) is smaller than crop=16"):
        fit_network(small, [], TINY)
    mismatched = [(torch.zeros(3, 20, 20, dtype=torch.uint8), torch.zeros(3, 20, 24, dtype=torch.uint8))]
    with pytest.raises(ValueError, match="same size"):
        fit_network(mismatched, [], TINY)
