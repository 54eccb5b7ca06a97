"""Issue 42, item 4: a fit whose own validation image-only critic tells the sampled profile from the captures says
so: a warning (log, ``fitted['warnings']``, the CLI's stderr) naming the statistics that differ most and the
``camdegrade diagnose`` command to run, quoted; ``--strict`` refuses to write such a profile."""

from __future__ import annotations

import shlex

import pytest
import torch

from bad_inputs import run_cli
from camdegrade import load_profile
from camdegrade.fitting.critic_warning import (
    CRITIC_WARNING_ACCURACY,
    critic_warning,
    diagnose_command,
    differing_statistics,
)
from camdegrade.io import write_image
from camdegrade.synthetic import dead_leaves_images

EDGES = [0.02, 0.08, 0.16, 0.25, 0.35, 0.5]


def _fidelity(accuracy: float | None, **statistics) -> dict:
    critic = None if accuracy is None else {"accuracy": accuracy, "low": accuracy - 0.05, "high": accuracy + 0.03}
    values = {"grid_ratio": 1.0, "bands": [0.0] * 5, "noise_ratio": 1.0, "banding_ratio": None} | statistics
    return {**values, "band_edges": EDGES, "critic_paired": {"accuracy": 0.99}, "critic_image_only": critic}


def test_a_critic_at_or_below_the_threshold_gives_no_warning() -> None:
    assert critic_warning(_fidelity(CRITIC_WARNING_ACCURACY, noise_ratio=0.1), "pairs") == []
    assert critic_warning(_fidelity(0.6), "pairs") == []
    assert len(critic_warning(_fidelity(0.72), "pairs")) == 1  # the phone camera's validation critic, 0.75 held out
    assert critic_warning(_fidelity(None, noise_ratio=0.1), "pairs") == []  # too few scenes for a critic
    assert critic_warning(None, "pairs") == [] and critic_warning({}, None) == []


def test_the_warning_names_the_statistics_that_differ_most_largest_first() -> None:
    fidelity = _fidelity(0.93, noise_ratio=0.125, grid_ratio=1.1, bands=[0.0, 0.1, -0.4, 0.3, -1.8])
    (warning,) = critic_warning(fidelity, "my pairs")
    assert "at 0.93 [0.88–0.96]" in warning
    assert "flat noise 0.12× the captures', band power 0.35–0.5 cycles/px -1.80 log2, band power 0.16–0.25" in warning
    assert "grid" not in warning  # 1.1× is log2 0.14: below what is named
    assert "`camdegrade diagnose PROFILE 'my pairs'`" in warning
    assert [round(far, 2) for far, _ in differing_statistics(fidelity)] == [3.0, 1.8, 0.4]


def test_without_a_differing_statistic_the_warning_says_where_the_difference_lies() -> None:
    (warning,) = critic_warning(_fidelity(0.99), None)
    assert "no statistic the fit measures" in warning and "texture they do not measure" in warning
    assert "`camdegrade diagnose PROFILE PAIRS`" in warning


@pytest.mark.parametrize("pairs", ["a b", "x; touch PWNED #", "$(rm -rf ~)", "it's", "line\nbreak", "-rf"])
def test_the_diagnose_command_splits_back_into_exactly_its_arguments(pairs: str) -> None:
    expected = ["camdegrade", "diagnose", "out dir/cam.safetensors", f"./{pairs}" if pairs[0] == "-" else pairs]
    assert shlex.split(diagnose_command("out dir/cam.safetensors", pairs)) == expected


def _noisy_camera_pairs(root, count: int = 12, size: int = 64) -> None:
    """A camera the network-only fit cannot reproduce: white noise of 20 levels on every capture."""
    generator = torch.Generator().manual_seed(5)
    for index, clean in enumerate(dead_leaves_images(count, size, seed=4)):
        noise = torch.randn(clean.shape, generator=generator) * 20
        captured = (clean.float() + noise).round().clamp(0, 255).to(torch.uint8)
        write_image(clean, root / "clean" / f"{index:02d}.png")
        write_image(captured, root / "captured" / f"{index:02d}.png")


@pytest.mark.slow
def test_a_fit_the_critic_sees_through_warns_and_the_cli_prints_the_command(tmp_path, capsys) -> None:
    pairs = tmp_path / "my pairs"
    _noisy_camera_pairs(pairs)
    output = tmp_path / "cam.safetensors"
    argv = ["fit", pairs, "-o", output, "--epochs", "1", "--crop", "32", "--crops-per-pair", "2"]
    argv += ["--val-fraction", "0.34", "--no-effects", "--quiet"]
    status, _, err = run_cli(argv, capsys)
    assert status == 0, err
    profile = load_profile(output)
    critic = profile.quality["fidelity"]["critic_image_only"]
    assert critic["accuracy"] > CRITIC_WARNING_ACCURACY, critic
    (warning,) = [text for text in profile.fitted["warnings"] if "image-only critic" in text]
    assert "flat noise" in warning and f"`camdegrade diagnose PROFILE {shlex.quote(str(pairs))}`" in warning
    assert f"camdegrade fit: warning: {warning}" in err.splitlines()
    (suggestion,) = [line for line in err.splitlines() if "to look for the cause:" in line]
    command = suggestion.split("to look for the cause: ", 1)[1]
    assert shlex.split(command) == ["camdegrade", "diagnose", str(output), str(pairs)]

    strict = tmp_path / "strict.safetensors"
    status, _, err = run_cli([*argv, "--strict", "-o", strict], capsys)
    assert status == 1 and not strict.exists() and "image-only critic" in err and "not written (--strict)" in err
