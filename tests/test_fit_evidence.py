"""Issue 23, items 4 and 5: a fit keeps only the effect stages the camera has (held-out evidence, recorded), and
reports its fidelity on the validation pairs (grid, bands, flat noise, a critic with and without the clean source),
in its metadata and in ``camdegrade fit`` / ``camdegrade info``."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

import camdegrade.fitting.steps.effects as effects_step
from bad_inputs import run_cli
from camdegrade import CameraProfile
from camdegrade._profile_format.summary import quality_lines
from camdegrade._support.pixels import bytes_to_unit, unit_to_bytes
from camdegrade.effects import Blur, Noise, Tone
from camdegrade.fitting import FitConfig, fit_profile
from camdegrade.fitting.steps import PairedFit
from camdegrade.fitting.steps.effects import EffectStage
from camdegrade.fitting.steps.noise_evidence import noise_evidence
from camdegrade.io import write_image
from camdegrade.measures.critic import repeated_critic_test, split_critic_test
from camdegrade.pairs import PairSet
from camdegrade.sim import VirtualCamera
from camdegrade.synthetic import dead_leaves_images
from steps_for_tests import paired_fit, run_step

torch.set_num_threads(1)
TONE = {"gamma": 0.8, "black": 0.02, "white": 0.95}


def _chart(size: int, seed: int) -> torch.Tensor:
    """2×2 flat grey patches at least 0.28 apart (no faint edge reads as flat), slightly tinted."""
    generator = torch.Generator().manual_seed(seed)
    grey = torch.linspace(0.08, 0.92, 4)[torch.randperm(4, generator=generator)]
    levels = (grey[None] * (0.9 + 0.2 * torch.rand(3, 1, generator=generator))).clamp(0, 1)
    return F.interpolate(levels.reshape(1, 3, 2, 2), size=(size, size), mode="nearest")[0]


def _cleans(count: int, size: int) -> list[torch.Tensor]:
    """Dead-leaves images (texture) and flat charts (noise is measured there), alternately, as uint8."""
    leaves = dead_leaves_images(count, size, seed=3)
    return [leaves[i] if i % 2 else unit_to_bytes(_chart(size, i)) for i in range(count)]


def _camera(noise: Noise | None) -> VirtualCamera:
    """Lens blur σ 0.7 (linear light), half the resolution, a tone curve; sensor noise only when given."""
    return VirtualCamera([Blur(0.7), *([noise] if noise is not None else []), Tone(**TONE)], scale=0.5)


def _pairs(camera: VirtualCamera, count: int = 12, size: int = 128) -> list[tuple[torch.Tensor, torch.Tensor]]:
    generator = torch.Generator().manual_seed(1)
    with torch.no_grad():
        return [(clean, camera(clean, generator=generator)) for clean in _cleans(count, size)]


QUICK = FitConfig.recipe("fast").replace(epochs=2, crop=32, crops_per_pair=4)


@pytest.mark.slow
def test_a_noiseless_camera_gets_no_noise_stage() -> None:
    lines: list[str] = []
    profile = fit_profile(_pairs(_camera(None)), QUICK.replace(val_fraction=0.25), log=lines.append)
    note = profile.fitted["effects"]["noise"]
    assert "noise" not in profile.effect_names
    assert note["kept"] is False and note["present"] is False and note["evidence"] == "validation"
    assert note["flat_pixels"] > 2000 and note["capture_noise"] < 0.3  # 8-bit captures of flat patches
    assert "not measurably above" in note["reason"]
    assert any(line.startswith("effect noise: dropped on 3 pair(s)") for line in lines), lines


@pytest.mark.slow
def test_a_noisy_camera_keeps_its_noise_at_its_level_and_reports_the_critic() -> None:
    lines: list[str] = []
    camera = _camera(Noise(a=0.003, b=2e-5))
    profile = fit_profile(_pairs(camera), QUICK.replace(val_fraction=0.34), log=lines.append)
    note = profile.fitted["effects"]["noise"]
    assert "noise" in profile.effect_names
    assert note["kept"] is True and note["present"] is True and note["evidence"] == "validation"
    assert note["capture_noise"] > 10 * note["simulation_noise"]
    assert note["noise_ratio_without"] < 0.2 and 0.8 <= note["noise_ratio_with"] <= 1.25
    fidelity = profile.quality["fidelity"]
    assert 0.8 <= fidelity["noise_ratio"] <= 1.25
    for key in ("critic_paired", "critic_image_only"):  # 4 validation scenes: 2 train a critic, 2 score it, and back
        critic = fidelity[key]
        assert critic["pairs"] == 4 and critic["patches"] == 4 * 2 * 24 and critic["critics"] == 4
        assert 0.0 <= critic["low"] <= critic["accuracy"] <= critic["high"] <= 1.0
        assert min(critic["accuracies"]) <= critic["accuracy"] <= max(critic["accuracies"]) and critic["std"] >= 0
    assert sum(line.startswith("fidelity: critic accuracy") for line in lines) == 2, lines


# --- the evidence itself, on a profile without a network (fast) ------------------------------------------------


def _evidence(
    camera_noise: Noise | None, stage: Noise, clean_noise: float = 0.0, count: int = 4
) -> tuple[Noise | None, dict]:
    """The stage kept for a profile that has the camera's tone curve, judged on ``count`` flat charts of that camera
    (holding noise of ``clean_noise`` 8-bit levels of their own, which the profile's output carries too)."""
    camera = VirtualCamera([*([camera_noise] if camera_noise is not None else []), Tone(**TONE)])
    generator = torch.Generator().manual_seed(2)
    cleans = [
        bytes_to_unit(unit_to_bytes(_chart(96, seed) + clean_noise / 255 * torch.randn(3, 96, 96, generator=generator)))
        for seed in range(count)
    ]
    with torch.no_grad():
        captures = [bytes_to_unit(unit_to_bytes(camera(clean, generator=generator))) for clean in cleans]
    kept, evidence = noise_evidence(CameraProfile(None, [Tone(**TONE)]), stage, cleans, captures, eight_bit=True)
    return kept, evidence.to_dict()


def test_banding_is_kept_only_where_it_brings_the_row_means_closer() -> None:
    banded_camera = Noise(a=0.002, b=1e-5, row_sigma=0.004)
    kept, evidence = _evidence(banded_camera, Noise(a=0.002, b=1e-5, row_sigma=0.004))
    assert kept is not None and float(kept.row_sigma.max()) > 0
    assert evidence["banding_kept"] is True
    assert abs(evidence["banding_ratio_banded"] - 1) < abs(evidence["banding_ratio_unbanded"] - 1)
    kept, evidence = _evidence(Noise(a=0.002, b=1e-5), Noise(a=0.002, b=1e-5, row_sigma=0.004))
    assert kept is not None and float(kept.row_sigma.max()) == 0  # the noise, without the banding
    assert evidence["banding_kept"] is False and evidence["banding_ratio_banded"] > 1.5


def test_noise_is_kept_only_where_it_brings_the_flat_noise_closer() -> None:
    kept, evidence = _evidence(Noise(a=0.002, b=1e-5), Noise(a=0.002, b=1e-5))
    assert kept is not None and evidence["kept"] and 0.8 <= evidence["noise_ratio_with"] <= 1.25
    kept, evidence = _evidence(None, Noise(a=0.002, b=1e-5))
    assert kept is None and not evidence["present"] and evidence["noise_ratio_with"] is None
    # the clean images' own noise gives the profile half the capture's: a stage of 10x the std is further off
    kept, evidence = _evidence(Noise(a=0.002, b=1e-5), Noise(a=0.002, b=1e-5).scaled(100.0), clean_noise=5.0)
    assert kept is None and evidence["present"] and 0.3 < evidence["noise_ratio_without"] < 0.8
    assert evidence["noise_ratio_with"] > 5 and evidence["reason"] == "no closer to the capture with it"


def test_noise_the_validation_pairs_do_not_show_is_not_fitted_and_noted_as_if_it_were(monkeypatch) -> None:
    """Whether the captures hold noise above the profile's is decided without the stage: where they do not, the
    fit by simulation is skipped (the costliest step of a City100 fit) and the record is what judging a fitted stage
    gives."""
    pairs = [(bytes_to_unit(clean), bytes_to_unit(captured)) for clean, captured in _pairs(_camera(None), count=8)]
    profile = CameraProfile(None, [Blur(0.7), Tone(**TONE)])
    judged_lines: list[str] = []
    judged = EffectStage(Noise).judge(paired_fit(profile, pairs[:4], pairs[4:], judged_lines.append), Noise(a=0.004))
    fitted: list[str] = []
    monkeypatch.setattr(effects_step, "fit_stage_in_chain", lambda *args, **kwargs: fitted.append("fit"))
    lines: list[str] = []
    kept, record = run_step(EffectStage(Noise), profile, pairs[:4], pairs[4:], lines.append)
    assert not fitted and kept.effect_names == profile.effect_names
    assert record == judged and not judged["present"] and not judged["kept"] and lines == judged_lines


def test_evidence_on_pairs_without_flat_pixels_says_so() -> None:
    leaves = [bytes_to_unit(image) for image in dead_leaves_images(2, 48, seed=0)]
    kept, evidence = noise_evidence(CameraProfile(None), Noise(a=0.002), leaves, leaves, eight_bit=True)
    assert kept is None and evidence.capture_noise is None and evidence.reason == "too few flat pixels to measure noise"


def test_validation_pairs_without_flat_pixels_leave_the_judgement_to_the_training_pairs() -> None:
    camera = VirtualCamera([Noise(a=0.002, b=1e-5), Tone(**TONE)])
    generator = torch.Generator().manual_seed(0)
    with torch.no_grad():
        charts = [(_chart(96, seed), camera(_chart(96, seed), generator=generator)) for seed in range(3)]
        leaves = [bytes_to_unit(image) for image in dead_leaves_images(2, 48, seed=0)]
        textured = [(leaf, camera(leaf, generator=generator)) for leaf in leaves]
    lines: list[str] = []
    train, val = PairSet.load(charts), PairSet.load(textured)
    profile = CameraProfile(None, [Tone(**TONE)])
    fit = PairedFit.of(train, train, val, profile=profile, seed=0, say=lines.append, arch="local_affine", refit=False)
    note = EffectStage(Noise).judge(fit, Noise(a=0.002, b=1e-5))
    assert [type(effect) for effect in fit.profile.effects] == [Noise, Tone] and note["kept"] and note["pairs"] == 3
    assert note["evidence"] == "training (the validation pairs hold too few flat pixels)"
    assert lines[-1].startswith("effect noise: kept on 3 pair(s)")
    assert lines[-1].endswith("[evidence: training (the validation pairs hold too few flat pixels)]")


# --- the critic on one set of pairs ---------------------------------------------------------------------------


def test_split_critic_test_alternates_scenes_and_needs_two() -> None:
    generator = torch.Generator().manual_seed(0)
    cleans = [torch.rand(3, 40, 40, generator=generator) for _ in range(4)]
    sims = [(clean * 0.5).clamp(0, 1) for clean in cleans]  # far from the captures: the critic tells at once
    result = split_critic_test((cleans, cleans, sims), ["b", "a", "d", "c"], seed=0, steps=30, image_only=True)
    assert result.pairs == 2 and result.patches == 2 * 2 * 24 and result.accuracy > 0.9
    with pytest.raises(ValueError, match=r"at least two scenes .* got 1 scene\(s\) for 4 pair\(s\)"):
        split_critic_test((cleans, cleans, sims), ["a"] * 4, seed=0)


# --- what people read --------------------------------------------------------------------------------------------


def test_quality_lines_show_psnr_fidelity_and_critic_and_nothing_else_from_the_file() -> None:
    quality = {
        "validation_pairs": 8,
        "identity_psnr_db": None,
        "baseline_psnr_db": 31.26,
        "network_psnr_db": 31.449,
        "profile_psnr_db": 30.6,
        "fidelity": {
            "grid_ratio": 0.764,
            "bands": [0.01, -0.3, None, "\x1b[2J", -2.2],
            "noise_ratio": 1.02,
            "banding_ratio": None,
            "critic_paired": {"accuracy": 0.62, "low": 0.55, "high": 0.7, "pairs": 4},
            "critic_image_only": None,
        },
    }
    lines = quality_lines(quality)
    assert lines[0] == (
        "validation 8 pairs: PSNR identity inf dB (identical) -> profile 30.60 dB (baseline 31.26 dB, network 31.45 dB)"
    )
    assert "grid 0.76, bands log2 +0.01 -0.30 n/a n/a -2.20, flat noise 1.02, banding n/a" in lines[1]
    assert lines[2].endswith("paired 0.62 [0.55-0.70], image-only not run (1 critic(s); 0.5: cannot tell)")
    quality["fidelity"]["critic_image_only"] = {"accuracy": 0.7, "low": 0.6, "high": 0.8, "pairs": 8, "std": 0.05,
                                                "critics": 4}  # fmt: skip
    assert quality_lines(quality)[2].endswith("image-only 0.70 ± 0.05 [0.60-0.80] (0.5: cannot tell)")
    assert "\x1b" not in "".join(lines) and quality_lines({"description": "no psnr"}) == []


def test_cli_fit_prints_the_quality_block_and_info_shows_it(tmp_path, capsys) -> None:
    for index, (clean, captured) in enumerate(_pairs(_camera(Noise(a=0.003, b=2e-5)), count=6, size=64)):
        write_image(clean, tmp_path / "pairs" / "clean" / f"{index}.png")
        write_image(captured, tmp_path / "pairs" / "captured" / f"{index}.png")
    out = tmp_path / "cam.safetensors"
    tiny = ["--epochs", "1", "--crop", "32", "--crops-per-pair", "2", "--val-fraction", "0.34", "--quiet"]
    code, printed, _ = run_cli(["fit", tmp_path / "pairs", "-o", out, *tiny], capsys)
    assert code == 0
    lines = printed.splitlines()
    start = next(index for index, line in enumerate(lines) if line.startswith("validation 2 pairs: PSNR identity "))
    block = lines[start : start + 3]
    assert "baseline " in block[0] and "network " in block[0] and "-> profile " in block[0]
    assert "fidelity: grid " in block[1] and block[2].endswith("paired not run, image-only not run (0.5: cannot tell)")
    assert "no critic (2 validation scene(s); it needs 4" in printed
    code, shown, _ = run_cli(["info", out], capsys)
    assert code == 0 and "\n".join(block) in shown


def _told_apart(count: int = 4) -> tuple[list[torch.Tensor], list[torch.Tensor], list[torch.Tensor]]:
    generator = torch.Generator().manual_seed(0)
    cleans = [torch.rand(3, 40, 40, generator=generator) for _ in range(count)]
    return cleans, cleans, [(clean * 0.5).clamp(0, 1) for clean in cleans]  # far from the captures


@pytest.mark.slow
def test_repeated_critics_score_every_pair_and_the_first_is_the_split_critic() -> None:
    pairs, scenes = _told_apart(), ["b", "a", "d", "c"]
    result = repeated_critic_test(pairs, scenes, seeds=2, steps=30, image_only=True)
    first = split_critic_test(pairs, scenes, seed=0, steps=30, image_only=True)
    assert len(result.accuracies) == 4 and result.accuracies[0] == first.accuracy  # seed 0, the first half trains
    assert result.pairs == 4 and result.patches == 4 * 2 * 24 and result.accuracy > 0.9
    assert min(result.accuracies) <= result.accuracy <= max(result.accuracies)
    assert result.low <= result.accuracy <= result.high
    again = repeated_critic_test(pairs, scenes, seeds=2, steps=30, image_only=True)
    assert again.accuracies == result.accuracies and (again.low, again.high) == (result.low, result.high)
    described = result.describe()
    assert described.startswith(f"critic accuracy {result.accuracy:.2f} ± {result.std:.2f} over 4 critics")
    stored = result.to_dict()
    assert stored["critics"] == 4 and stored["accuracies"] == [round(a, 3) for a in result.accuracies]


def test_repeated_critics_cannot_tell_a_simulation_that_is_the_capture() -> None:
    cleans, reals, _ = _told_apart(6)
    result = repeated_critic_test((cleans, reals, reals), list("abcdef"), seeds=2, steps=30, image_only=True)
    assert result.accuracy == 0.5 and result.std == 0.0  # every patch twice, once with each label


@pytest.mark.parametrize(
    ("scenes", "seeds", "message"),
    [
        (["a"] * 4, 2, r"at least two scenes .* got 1 scene\(s\) for 4 pair\(s\)"),
        (["a", "b", "c", "d"], 0, r"seeds must be a positive integer, got seeds=0"),
        (["a", "b", "c", "d"], True, r"seeds must be a positive integer, got seeds=True"),
    ],
)
def test_repeated_critics_refuse_what_they_cannot_do(scenes, seeds, message) -> None:
    with pytest.raises(ValueError, match=message):
        repeated_critic_test(_told_apart(), scenes, seeds)
