"""The network trainer: learns, is deterministic, checkpoints atomically, resumes exactly, survives Ctrl-C."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from camdegrade.fitting.network.checkpoint import load_checkpoint
from camdegrade.fitting.network.training import EpochResult, FitInterrupted, evaluate_psnr, fit_network
from camdegrade.fitting.recipe import FitConfig

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


def test_a_step_schedule_resumes_for_more_epochs_exactly(tmp_path):
    pairs = synthetic_pairs()
    stepped = FitConfig(**{**TINY.as_dict(), "schedule": "step", "lr_halving_epochs": 1})
    straight, straight_history = fit_network(pairs[:3], pairs[3:], stepped)
    checkpoint = tmp_path / "fit.ckpt.safetensors"
    half = FitConfig(**{**stepped.as_dict(), "epochs": 2})
    fit_network(pairs[:3], pairs[3:], half, checkpoint=checkpoint)
    assert load_checkpoint(checkpoint).epoch == 2
    resumed, history = fit_network(pairs[:3], pairs[3:], stepped, checkpoint=checkpoint, resume=True)
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


@pytest.mark.parametrize("change", [{"lr": 0.001}, {"epochs": 5}, {"precision": "float32"}])
def test_resume_refuses_a_different_recipe(tmp_path, change):
    """Another lr or precision, or another length of a cosine schedule (laid out over the epochs)."""
    pairs = synthetic_pairs()
    checkpoint = tmp_path / "fit.ckpt.safetensors"
    fit_network(
        pairs[:3], [], FitConfig(**{**TINY.as_dict(), "epochs": 1, "precision": "bfloat16"}), checkpoint=checkpoint
    )
    with pytest.raises(ValueError, match="different recipe"):
        fit_network(
            pairs[:3],
            [],
            FitConfig(**{**TINY.as_dict(), "precision": "bfloat16", **change}),
            checkpoint=checkpoint,
            resume=True,
        )


def test_callback_sees_every_epoch():
    seen = []
    config = FitConfig.recipe("paper", epochs=3, crop=16, batch_size=4, crops_per_pair=2)
    fit_network(synthetic_pairs()[:2], [], config, callback=seen.append)
    assert [r.epoch for r in seen] == [1, 2, 3] and all(r.lr == 0.01 for r in seen)


def test_the_paper_recipe_halves_the_learning_rate_every_30_epochs():
    paper = {"epochs": 100, "crop": 128, "batch_size": 32, "lr": 0.01, "lr_halving_epochs": 30, "crops_per_pair": 8}
    steps = (("resolution", {"scale": 1.0}), ("effects", {"names": ("noise", "vignetting")}))
    expected = FitConfig(**paper, schedule="step", patience=0, arch="paper", curves="none", steps=steps)
    assert FitConfig.recipe("paper") == expected
    seen = []
    config = FitConfig.recipe("paper", epochs=31, crop=16, batch_size=8, crops_per_pair=1)
    fit_network(synthetic_pairs(2, 16), [], config, callback=seen.append)
    assert seen[29].lr == pytest.approx(0.01) and seen[30].lr == pytest.approx(0.005)


def test_the_default_recipe_lowers_the_learning_rate_along_a_cosine():
    seen = []
    config = FitConfig(epochs=4, crop=16, batch_size=8, crops_per_pair=1, lr=0.004)
    fit_network(synthetic_pairs(2, 16), [], config, callback=seen.append)
    expected = [0.004 * (1 + math.cos(math.pi * epoch / 4)) / 2 for epoch in range(4)]
    assert [r.lr for r in seen] == pytest.approx(expected)


def test_early_stopping_keeps_the_best_epoch(monkeypatch):
    """Scores that stop rising by 0.01 dB after epoch 2: with patience 3 the fit ends after epoch 5 (the best
    weights are epoch 3's, higher by less than the progress step)."""
    import camdegrade.fitting.network.training as training

    scores = iter([20.0, 21.0, 21.005, 20.5, 20.9, 30.0, 30.0])
    monkeypatch.setattr(training, "evaluate_psnr", lambda network, pairs, device="cpu", after=None: next(scores))
    seen = []
    pairs = synthetic_pairs()
    config = FitConfig(**{**TINY.as_dict(), "epochs": 7, "patience": 3})
    _, history = fit_network(pairs[:3], pairs[3:], config, callback=seen.append)
    assert [r.epoch for r in history] == [1, 2, 3, 4, 5]
    assert [r.is_best for r in history] == [True, True, True, False, False]
    assert [r.epoch for r in seen] == [1, 2, 3, 4, 5]


def test_no_early_stopping_without_validation_pairs():
    config = FitConfig(**{**TINY.as_dict(), "epochs": 3, "patience": 1, "lr": 1e-12})  # the loss barely moves
    _, history = fit_network(synthetic_pairs()[:3], [], config)
    assert len(history) == 3


def test_bfloat16_training_learns_and_repeats():
    pairs = synthetic_pairs()
    config = FitConfig(**{**TINY.as_dict(), "precision": "bfloat16"})
    first, history = fit_network(pairs[:3], pairs[3:], config)
    second, _ = fit_network(pairs[:3], pairs[3:], config)
    assert history[-1].train_loss < history[0].train_loss
    assert weights_bytes(first) == weights_bytes(second)
    assert all(p.dtype == torch.float32 for p in first.parameters())


def test_the_progress_bar_counts_every_step(capsys):
    config = FitConfig(**{**TINY.as_dict(), "epochs": 2})  # 3 pairs × 4 crops / batch 4 = 3 steps per epoch
    fit_network(synthetic_pairs()[:3], [], config, progress=True)
    assert "6/6" in capsys.readouterr().err


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("epochs", 0, "epochs must be a positive integer, got epochs=0"),
        ("crop", 30, "crop must be a multiple of 4, got crop=30"),
        ("lr", -1.0, "lr must be a positive number, got lr=-1.0"),
        ("batch_size", 2.5, "batch_size must be a positive integer"),
        ("patience", -1, "patience must be an integer >= 0"),
        ("schedule", "linear", "schedule must be one of"),
        ("precision", "float16", "precision must be one of"),
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
