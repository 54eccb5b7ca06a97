"""The local-affine network's pointwise curves (``curves=True``, the fast recipe's ``curves="channel"``): one learned
curve per channel before its filter and one after its colour transform."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from camdegrade import CameraProfile, load_profile
from camdegrade import network as network_module
from camdegrade._profile_format import network_entry
from camdegrade._support.recipes import CURVES, FAST, PAPER
from camdegrade.errors import ProfileError
from camdegrade.fitting import FitConfig
from camdegrade.fitting.network.training import fit_network, new_network
from camdegrade.functional import srgb_to_linear
from camdegrade.measures.metrics import psnr
from camdegrade.network import CURVE_KNOTS, LocalAffineNet, build_network, piecewise_linear
from camdegrade.synthetic import dead_leaves_images
from test_profile_validation import ProfileParts


def _bent(network: LocalAffineNet, seed: int) -> LocalAffineNet:
    """``network`` with every parameter moved a little and both curves bent away from the identity."""
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for parameter in network.parameters():
            parameter.add_(torch.randn(parameter.shape, generator=generator) * 0.03)
        network.curve.copy_(network.curve.clamp(0, 1) ** torch.tensor([0.7, 1.0, 1.4]).view(1, 3, 1))
    return network.eval()


def test_a_curve_passes_through_its_knots_and_is_linear_between_them() -> None:
    knots = torch.stack([torch.linspace(0, 1, 5) ** 2, torch.linspace(1, 0, 5), torch.full((5,), 0.3)])
    image = torch.tensor([0.0, 0.25, 0.375, 1.0, -0.5, 1.5]).view(1, 1, 1, 6).expand(1, 3, 1, 6)
    out = piecewise_linear(image, knots)[0, :, 0]
    assert torch.allclose(out[0], torch.tensor([0.0, 0.0625, (0.0625 + 0.25) / 2, 1.0, 0.0, 1.0]))  # ends held
    assert torch.allclose(out[1], torch.tensor([1.0, 0.75, 0.625, 0.0, 1.0, 0.0]))
    assert torch.equal(out[2], torch.full((6,), 0.3))


def test_a_curve_has_the_gradients_of_its_formula_summed_in_a_fixed_order() -> None:
    image = torch.rand(1, 3, 5, 6, dtype=torch.double, generator=torch.Generator().manual_seed(0)) * 1.2 - 0.1
    knots = torch.linspace(0, 1, 5, dtype=torch.double).repeat(3, 1) ** torch.tensor([[0.5], [1.0], [2.0]])
    assert torch.autograd.gradcheck(piecewise_linear, (image.requires_grad_(), knots.requires_grad_()))
    big = torch.rand(8, 3, 64, 64, generator=torch.Generator().manual_seed(1))
    grads = []
    for _ in range(3):  # a gather's own backward (index_put with accumulate) gave other bytes run to run
        curve = torch.linspace(0, 1, CURVE_KNOTS).repeat(3, 1).requires_grad_()
        (piecewise_linear(big, curve) * torch.sin(50 * big)).sum().backward()
        grads.append(curve.grad)
    assert all(torch.equal(grads[0], grad) for grad in grads[1:])
    with torch.no_grad():  # inference takes another path to the same bytes
        inferred = piecewise_linear(big, curve)
    assert torch.equal(inferred, piecewise_linear(big, curve).detach())


def test_curves_start_as_the_identity_and_each_bends_its_own_channel() -> None:
    network = LocalAffineNet(4, curves=True)
    assert network.curve.shape == (2, 3, CURVE_KNOTS)
    image = torch.rand(2, 3, 13, 18, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        assert torch.allclose(network(image), image, atol=1e-6)
        network.curve[1, 0] = network.curve[1, 0] ** 2  # the output curve of red alone
        out = network(image)
    assert torch.allclose(out[:, 1:], image[:, 1:], atol=1e-6)
    assert float((out[:, 0] - image[:, 0] ** 2).abs().max()) < 1 / (4 * (CURVE_KNOTS - 1) ** 2) + 1e-6  # chords


def test_the_recipes_choose_the_curves_and_a_start_must_match_them() -> None:
    assert CURVES == ("none", "channel") and FAST["curves"] == "channel" and PAPER["curves"] == "none"
    assert new_network(FitConfig(width=4)).curves is True
    assert new_network(FitConfig(width=4, curves="none")).curves is False
    assert "curves" in FitConfig().training_dict()
    assert build_network("paper", 4, curves=True).config() == {"width": 4}  # the paper network has none
    with pytest.raises(ValueError, match=r"curves must be one of \('none', 'channel'\), got curves='tone'"):
        FitConfig(curves="tone")
    images = dead_leaves_images(2, 32, seed=8)
    pairs = [(image, image) for image in images]
    with pytest.raises(ValueError, match=r"curves True .*got arch='local_affine', width=64, curves=False"):
        fit_network(pairs, [], FitConfig(epochs=1, crop=32), initial=LocalAffineNet())


def test_profiles_keep_the_curves_and_older_profiles_load_without_them(tmp_path) -> None:
    network = _bent(LocalAffineNet(4, curves=True), 1)
    path = CameraProfile(network, name="curved").save(tmp_path / "curved.safetensors")
    loaded = load_profile(path)
    assert loaded.metadata()["network"]["config"] == {"width": 4, "upsample": "bilinear", "curves": True}
    image = torch.rand(1, 3, 20, 24, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        assert torch.equal(loaded.network(image), network(image))
        assert not torch.allclose(network(image), image, atol=1e-2)  # the bent curves show
    plain = CameraProfile(LocalAffineNet(4), name="plain").save(tmp_path / "plain.safetensors")
    assert load_profile(plain).network.curves is False
    assert "curves" not in load_profile(plain).metadata()["network"]["config"]  # files as before the option


@pytest.mark.parametrize("value", ["yes", 1, None])
def test_a_curves_value_that_is_not_a_bool_is_refused_by_the_network_and_the_profile_check(tmp_path, value) -> None:
    with pytest.raises(ValueError, match="curves must be True or False, got curves="):
        LocalAffineNet(4, curves=value)
    parts = ProfileParts(CameraProfile(LocalAffineNet(4, curves=True), name="x").save(tmp_path / "x.safetensors"))
    parts.metadata["network"]["config"]["curves"] = value
    with pytest.raises(ProfileError, match="curves must be True or False"):
        load_profile(parts.write(tmp_path / "bad.safetensors"))


def test_a_file_whose_curves_disagree_with_its_tensors_is_refused(tmp_path) -> None:
    parts = ProfileParts(CameraProfile(LocalAffineNet(4), name="x").save(tmp_path / "x.safetensors"))
    parts.metadata["network"]["config"]["curves"] = True  # declares a curve tensor the file does not hold
    with pytest.raises(ProfileError, match=r"network\.curve"):
        load_profile(parts.write(tmp_path / "bad.safetensors"))
    assert network_entry.CURVE_KNOTS == network_module.CURVE_KNOTS  # the torch-free copy the profile check uses


def _soft_camera(image: torch.Tensor) -> torch.Tensor:
    """A lens blur in linear light (σ about 1 px), then a tone curve: what a shift-invariant filter on sRGB values
    cannot follow across an edge."""
    taps = torch.tensor([1.0, 4.0, 6.0, 4.0, 1.0]) / 16
    linear = F.pad(srgb_to_linear(image), (2, 2, 2, 2), mode="replicate")
    blurred = F.conv2d(linear, taps.view(1, 1, 1, 5).expand(3, 1, 1, 5), groups=3)
    blurred = F.conv2d(blurred, taps.view(1, 1, 5, 1).expand(3, 1, 5, 1), groups=3)
    return (0.05 + 0.9 * blurred.clamp(0, 1) ** 0.45).clamp(0, 1)


def test_with_the_curves_a_fit_follows_a_blur_in_linear_light_before_a_tone_curve() -> None:
    cleans = [image.float() / 255 for image in dead_leaves_images(10, 48, seed=5)]
    pairs = [(clean, _soft_camera(clean[None])[0]) for clean in cleans]
    train, val = pairs[:8], pairs[8:]
    scores = {}
    for curves in CURVES:
        config = FitConfig(epochs=6, crop=48, crops_per_pair=8, width=8, lr=0.01, patience=0, curves=curves)
        network, _ = fit_network(train, val, config)
        with torch.no_grad():
            scores[curves] = sum(float(psnr(network(c[None])[0], t)) for c, t in val) / len(val)
    assert scores["channel"] > scores["none"] + 1.0, scores
