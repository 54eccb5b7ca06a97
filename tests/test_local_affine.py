"""The grid-free network (``arch="local_affine"``) and the least-squares linear baseline it starts from."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from camdegrade import CameraProfile, load_profile
from camdegrade import network as network_module
from camdegrade._support.recipes import ARCHS, FAST, PAPER, UPSAMPLINGS
from camdegrade.errors import ProfileError
from camdegrade.fitting import FitConfig
from camdegrade.fitting.network.baseline import apply_linear_baseline, baseline_psnr, fit_linear_baseline
from camdegrade.fitting.network.training import fit_network, new_network
from camdegrade.measures.fidelity import grid_rms
from camdegrade.network import ARCHITECTURES, DomainShiftNet, LocalAffineNet, build_network, smoothed
from camdegrade.synthetic import dead_leaves_images
from conftest import PAPER_BUILT_IN
from test_profile_validation import ProfileParts


def _randomised(network: torch.nn.Module, seed: int) -> torch.nn.Module:
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for parameter in network.parameters():
            parameter.copy_(torch.randn(parameter.shape, generator=generator) * 0.2)
    return network.eval()


def test_the_recipes_name_the_architectures_the_network_module_builds() -> None:
    assert tuple(ARCHITECTURES) == ARCHS
    assert (FAST["arch"], PAPER["arch"]) == ("local_affine", "paper")
    assert type(build_network("paper", 8)) is DomainShiftNet
    assert type(build_network("local_affine", 8)) is LocalAffineNet
    with pytest.raises(ValueError, match=r"arch must be one of \('paper', 'local_affine'\), got arch='unet'"):
        build_network("unet")
    with pytest.raises(ValueError, match="arch must be one of"):
        FitConfig(arch="unet")


def test_a_fresh_local_affine_network_passes_the_image_through_at_any_size() -> None:
    for size in ((1, 1), (5, 7), (64, 48)):
        image = torch.rand(2, 3, *size, generator=torch.Generator().manual_seed(1))
        assert torch.equal(LocalAffineNet(8)(image), image)


def test_on_a_flat_image_the_paper_network_prints_a_4_pixel_period_and_local_affine_none() -> None:
    flat = torch.full((1, 3, 64, 64), 0.4)
    with torch.no_grad():
        paper = _randomised(DomainShiftNet(8), 0)(flat)[0, :, 8:-8, 8:-8]
        local = _randomised(LocalAffineNet(8), 0)(flat)[0, :, 8:-8, 8:-8]
    # The paper's output repeats every 4 pixels (the transposed convolutions' taps) and varies within a period.
    assert torch.allclose(paper[:, :-4], paper[:, 4:], atol=1e-6)
    assert float(paper.std()) > 1e-3
    # The local-affine one is flat wherever its input is: a smooth field times a filtered constant.
    assert float(local.std(dim=(1, 2)).max()) < 1e-5


def test_on_a_photo_like_image_local_affine_adds_no_grid_where_the_paper_network_does() -> None:
    image = dead_leaves_images(1, 96, seed=3)[0].float()[None] / 255
    with torch.no_grad():
        paper = _randomised(DomainShiftNet(8), 1)(image)
        local = _randomised(LocalAffineNet(8), 1)(image)

    def grid_share(picture: torch.Tensor) -> float:  # the 4×4-periodic pattern against the image's contrast
        return grid_rms(picture[0]) / (255 * float(picture.std()))

    assert grid_share(paper) > 5 * grid_share(image)
    assert grid_share(local) < 1.5 * grid_share(image)


def test_profiles_record_the_architecture_and_load_it_back(tmp_path) -> None:
    network = _randomised(LocalAffineNet(4), 2)
    path = CameraProfile(network, name="la").save(tmp_path / "la.safetensors")
    loaded = load_profile(path)
    assert loaded.metadata()["network"] == {"arch": "LocalAffineNet", "config": {"width": 4, "upsample": "bilinear"}}
    assert type(loaded.network) is LocalAffineNet
    image = torch.rand(1, 3, 20, 24, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        assert torch.equal(loaded.network(image), network(image))
    assert "LocalAffineNet({'upsample': 'bilinear', 'width': 4})" in loaded.describe()  # keys sorted, as info shows


def test_a_profile_written_before_the_smooth_field_loads_with_its_bilinear_field(tmp_path) -> None:
    """Older profiles hold no ``upsample`` key: they load as the bilinear field they were fitted with, same bytes."""
    network = _randomised(LocalAffineNet(4, upsample="bilinear"), 3)
    parts = ProfileParts(CameraProfile(network, name="old").save(tmp_path / "new.safetensors"))
    del parts.metadata["network"]["config"]["upsample"]
    loaded = load_profile(parts.write(tmp_path / "old.safetensors"))
    assert loaded.network.upsample == "bilinear"
    image = torch.rand(1, 3, 20, 24, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        assert torch.equal(loaded.network(image), network(image))
        smooth = LocalAffineNet(4, upsample="smooth")
        smooth.load_state_dict(network.state_dict())
        assert not torch.allclose(smooth.eval()(image), network(image), atol=1e-3)  # the key decides the output


@pytest.mark.parametrize("upsample", ["cubic", None, 1])
def test_an_unknown_field_upsampling_is_refused_by_the_network_and_the_profile_check(tmp_path, upsample) -> None:
    with pytest.raises(ValueError, match=r"upsample must be one of \('bilinear', 'smooth'\), got upsample="):
        LocalAffineNet(4, upsample=upsample)
    parts = ProfileParts(CameraProfile(LocalAffineNet(4, "smooth"), name="x").save(tmp_path / "x.safetensors"))
    parts.metadata["network"]["config"]["upsample"] = upsample
    with pytest.raises(ProfileError, match="upsample must be one of"):
        load_profile(parts.write(tmp_path / "bad.safetensors"))
    assert network_module.FIELD_UPSAMPLING == UPSAMPLINGS  # the torch-free copy the profile check uses


def test_the_recipe_chooses_the_colour_field_and_a_refit_keeps_its_start() -> None:
    assert FitConfig().upsample == "bilinear" and "upsample" in FitConfig().training_dict()
    assert build_network("local_affine", 4, "smooth").upsample == "smooth"
    with pytest.raises(ValueError, match=r"upsample must be one of \('bilinear', 'smooth'\), got upsample='cubic'"):
        FitConfig(upsample="cubic")
    network = new_network(FitConfig(width=4, upsample="smooth"))
    assert isinstance(network, LocalAffineNet)
    assert network.config() == {"width": 4, "upsample": "smooth", "curves": True}


def test_the_smooth_field_keeps_a_constant_and_a_ramp_and_bends_at_every_phase_alike() -> None:
    constant = torch.full((1, 12, 6, 7), 0.3)
    assert torch.allclose(smoothed(constant), constant, atol=1e-7)
    ramp = torch.arange(64.0).view(1, 1, 1, 64).expand(1, 1, 8, 64)
    assert torch.allclose(smoothed(ramp)[..., 8:-8], ramp[..., 8:-8], atol=1e-5)  # symmetric taps: no shift
    samples = torch.rand(1, 1, 1, 64, generator=torch.Generator().manual_seed(0)).expand(1, 1, 4, 64)
    bilinear = F.interpolate(samples, scale_factor=4, mode="bilinear", align_corners=False)

    def curvature_by_phase(field: torch.Tensor) -> torch.Tensor:  # mean |second difference| per (x mod 4)
        curve = field[0, 0, 0, 8:-8]
        bend = (curve[2:] - 2 * curve[1:-1] + curve[:-2]).abs()
        return torch.stack([bend[phase::4][:60].mean() for phase in range(4)])

    # Bilinear: the slope changes only where a sample lies (2 of the 4 phases); smooth: at every phase alike.
    rough, smooth = curvature_by_phase(bilinear), curvature_by_phase(smoothed(bilinear))
    assert float(rough.min() / rough.max()) < 1e-4
    assert float(smooth.min() / smooth.max()) > 0.5


def test_profiles_of_the_paper_network_still_load_and_the_built_ins_are_grid_free() -> None:
    assert type(load_profile(PAPER_BUILT_IN).network) is DomainShiftNet
    assert type(load_profile("city100-iphonex").network) is LocalAffineNet


def test_the_linear_baseline_recovers_a_known_colour_filter() -> None:
    kernel = torch.zeros(3, 3, 3, 3)
    kernel[:, :, 1, 1] = torch.tensor([[0.8, 0.1, 0.0], [0.0, 0.7, 0.1], [0.1, 0.0, 0.6]])
    kernel[0, 0] += torch.tensor([[0.0, 0.05, 0.0], [0.05, -0.2, 0.05], [0.0, 0.05, 0.0]])
    bias = torch.tensor([0.05, -0.02, 0.1])
    cleans = [image.float() / 255 for image in dead_leaves_images(3, 64, seed=5)]
    pairs = [(clean, F.conv2d(F.pad(clean[None], (1, 1, 1, 1), mode="replicate"), kernel, bias)[0]) for clean in cleans]
    weight, fitted_bias = fit_linear_baseline(pairs, seed=0)
    expected = F.pad(kernel, (2, 2, 2, 2))  # the 3×3 filter inside the 7×7 taps
    assert torch.allclose(weight, expected, atol=2e-3)
    assert torch.allclose(fitted_bias, bias, atol=2e-3)
    assert baseline_psnr(weight, bias, pairs) > 50


def test_the_linear_baseline_is_seeded_and_refuses_no_pairs() -> None:
    cleans = [image.float() / 255 for image in dead_leaves_images(2, 48, seed=6)]
    pairs = [
        (clean, (clean * 0.9 + 0.03 * torch.rand(clean.shape, generator=torch.Generator())).clamp(0, 1))
        for clean in cleans
    ]
    first, second = fit_linear_baseline(pairs, seed=4), fit_linear_baseline(pairs, seed=4)
    assert all(torch.equal(a, b) for a, b in zip(first, second, strict=True))
    with pytest.raises(ValueError, match="pairs must hold at least one"):
        fit_linear_baseline([])
    output = apply_linear_baseline(*first, cleans[0][None])
    assert output.shape == (1, 3, 48, 48) and float(output.min()) >= 0 and float(output.max()) <= 1


def test_a_fit_that_never_beats_its_start_returns_the_start() -> None:
    """A learning rate that wrecks the network: every epoch scores below the starting network on validation, so the
    fit returns the start (best epoch 0) rather than something worse."""
    images = dead_leaves_images(4, 64, seed=7)
    pairs = [(image, (image.float() * 0.8 + 10).clamp(0, 255).to(torch.uint8)) for image in images]
    config = FitConfig(epochs=2, crop=32, batch_size=4, crops_per_pair=2, lr=5.0, patience=0, precision="float32")
    start = LocalAffineNet(config.width, curves=True)
    with torch.no_grad():
        start.linear.weight.mul_(0.8)
        start.linear.bias.fill_(10 / 255)
    network, history = fit_network(pairs[:3], pairs[3:], config, initial=start)
    assert not any(result.is_best for result in history)
    assert all(torch.equal(a, b) for a, b in zip(network.state_dict().values(), start.state_dict().values()))


def test_a_start_of_another_architecture_is_refused() -> None:
    images = dead_leaves_images(2, 32, seed=8)
    pairs = [(image, image) for image in images]
    with pytest.raises(ValueError, match="initial must be a network of arch 'local_affine', width 64 and curves True"):
        fit_network(pairs, [], FitConfig(epochs=1, crop=32), initial=DomainShiftNet())


def test_a_fit_that_ends_while_still_rising_says_so() -> None:
    from camdegrade.fitting.network.training import EpochResult
    from camdegrade.fitting.quality import still_rising

    config = FitConfig(epochs=3)
    rising = [EpochResult(i + 1, 0.1, psnr, 0.001, True) for i, psnr in enumerate((25.0, 25.5, 25.8))]
    flat = [*rising[:2], EpochResult(3, 0.1, 25.52, 0.001, True)]
    stopped = [*rising[:2], EpochResult(3, 0.1, 25.9, 0.001, False)]
    assert "still rising at the last epoch (+0.30 dB" in still_rising(rising, config)[0]
    assert "--epochs 6" in still_rising(rising, config)[0]
    assert still_rising(flat, config) == [] and still_rising(stopped, config) == []
    assert still_rising(rising[:2], config) == []  # stopped early by patience: it did not run out of epochs
