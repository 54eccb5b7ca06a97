"""A chain's plan (``camdegrade.effects.plan``): adjacent linear shift-invariant stages composed into one filter at
inference, every other stage as itself; the output that of running the stages one by one, and never saved."""

from __future__ import annotations

import pytest
import torch
from safetensors import safe_open
from skimage import data

from camdegrade import CameraDegrade, load_profile
from camdegrade.effects import Blur, Denoise, FrequencyResponse, Noise, Sharpen, Tone
from camdegrade.effects.chain import apply_effects, apply_stages
from camdegrade.effects.plan import ChainPlan, FilterRun, chain_plan
from camdegrade.network.inference import run_network
from effects_images import photo_batch

BUILT_INS = ("city100-iphonex", "city100-iphonex-fast", "lowcost-robot-sim")
#: The images the built-ins are held to: a photograph at 224², odd sizes, a batch, and sizes the filters' radii
#: exceed (where the composed stages run one by one).
SIZES = [(1, 224, 224), (1, 37, 61), (3, 65, 47), (2, 9, 5), (1, 2, 3)]


def _steps(plan: ChainPlan) -> list:
    return [step.indices if isinstance(step, FilterRun) else step for step in plan.steps]


def _photo(count: int, height: int, width: int) -> torch.Tensor:
    """``count`` different crops of scikit-image's astronaut as uint8 ``(count, 3, height, width)``."""
    full = torch.from_numpy(data.astronaut()).permute(2, 0, 1)
    return torch.stack([full[:, 40 * i : 40 * i + height, 60 * i : 60 * i + width] for i in range(count)]).contiguous()


def _bytes(image: torch.Tensor) -> torch.Tensor:
    return (image * 255).round()


def test_the_built_in_plans_compose_blur_and_sharpening_and_split_at_the_noise_reduction():
    profile = load_profile("city100-iphonex")
    assert profile.effect_names == ["jitter", "blur", "sharpen", "denoise", "frequency_response"]
    assert _steps(chain_plan(profile.effects)) == [0, (1, 2), 3, (4,)]
    robot = load_profile("lowcost-robot-sim")  # distortion, noise, resolution: none is a filter
    assert _steps(chain_plan(robot.effects)) == [0, 1, 2, (3,)]


@pytest.mark.parametrize("name", BUILT_INS)
@pytest.mark.parametrize("shape", SIZES)
def test_the_planned_chain_is_the_stage_by_stage_chain_within_one_level(name, shape):
    """The plan against each stage's ``forward`` in turn, after the same network output: within one 8-bit level
    everywhere and equal on at least 99.9 % of the values."""
    profile = load_profile(name)
    image = _photo(*shape)
    with torch.no_grad():
        network = run_network(profile.network, image, "float32")
        params = profile.make_params(network.shape, torch.Generator().manual_seed(1))
        planned = apply_effects(profile.effects, params, network)
        stages = apply_stages(profile.effects, params, network)
    assert (planned - stages).abs().max() < 2e-6
    levels = (_bytes(planned) - _bytes(stages)).abs()
    assert float(levels.max()) <= 1 and float((levels == 0).float().mean()) >= 0.999


@pytest.mark.parametrize("name", BUILT_INS)
def test_camdegrade_is_the_modules_stage_by_stage_output_within_one_level(name):
    """The whole call, planned (the network's CPU plan, then the chain's plan) against the network module and each
    stage's forward: within one level on at least 99.9 % of the pixels of photographs, odd sizes and a batch."""
    degrade = CameraDegrade(name, precision="float32")
    profile = degrade.profile
    within, count, largest = 0, 0, 0.0
    for shape in SIZES[:4]:
        image = _photo(*shape)
        params = degrade.make_params([image])
        planned = degrade.transform(image, params).float()
        with torch.no_grad():
            reference = apply_stages(profile.effects, params["effects"], profile.network(image.float() / 255))
        levels = (planned - _bytes(reference.clamp(0, 1))).abs()
        within, count, largest = within + int((levels <= 1).sum()), count + levels.numel(), max(largest, levels.max())
    assert within / count >= 0.999 and largest <= 2


def test_a_saved_and_reloaded_profile_keeps_its_stages_and_no_plan(tmp_path):
    profile = load_profile("city100-iphonex")
    profile(_photo(1, 32, 32))  # plans its chain
    path = profile.save(tmp_path / "again.safetensors")
    again = load_profile(path)
    assert again.effect_names == profile.effect_names
    assert [effect.config() for effect in again.effects] == [effect.config() for effect in profile.effects]
    for ours, theirs in zip(again.effects, profile.effects, strict=True):
        assert ours.state_dict().keys() == theirs.state_dict().keys()
        assert all(torch.equal(ours.state_dict()[k], theirs.state_dict()[k]) for k in ours.state_dict())
    with safe_open(str(path), framework="pt") as handle:
        assert set(handle.keys()) == set(profile.state_dict())  # the fitted tensors, nothing composed


def test_a_clamping_stage_ends_a_run_and_a_non_linear_one_splits_it():
    chain = [Blur(0.8, linear=False), Sharpen(1.0, 0.8), FrequencyResponse(torch.full((5, 5), 1.2)), Blur(0.5)]
    assert _steps(chain_plan(chain)) == [(0, 1), (2,), (3,)]  # the blur after the response is linear-light
    chain = [Blur(0.8, linear=False), Denoise(1.0, 0.02), Blur(0.6, linear=False), Denoise(1.0, 0.0), Tone(1.1)]
    assert _steps(chain_plan(chain)) == [(0,), 1, (2, 3), 4]
    chain = [Blur(0.8), Noise(0.01), Blur(0.6), Blur(0.7)]
    assert _steps(chain_plan(chain)) == [(0,), 1, (2, 3)]


#: Chains whose filters differ from the built-ins', with the plan's steps: a rotated, anisotropic PSF with motion
#: (not separable, not symmetric about the axes: a later stage reads its output's border mirrored, which no composed
#: filter reproduces, so the run ends there; composed, the border would differ by up to 15 levels), a response after
#: a blur (a product of spectra after separable passes), two linear-light blurs, per-channel sharpening.
CHAINS = {
    "rotated blur, blur, sharpen": (
        lambda: [Blur(1.4, 0.6, 30.0, 3.0, 20.0, linear=False), Blur(0.8, linear=False), Sharpen(1.2, 1.3)],
        [(0,), (1, 2)],
    ),
    "blur, response": (
        lambda: [Blur(0.7, linear=False), FrequencyResponse(torch.linspace(0.6, 2.5, 121).reshape(11, 11))],
        [(0, 1)],
    ),
    "two linear-light blurs": (lambda: [Blur(0.9), Blur(1.3, 0.7)], [(0, 1)]),
    "per-channel sharpen": (lambda: [Blur(0.6, linear=False), Sharpen(0.8, 2.0, luma=False)], [(0, 1)]),
}


@pytest.mark.parametrize("chain", CHAINS)
def test_other_composed_filters_follow_their_stages(chain):
    make, steps = CHAINS[chain]
    effects = make()
    assert _steps(chain_plan(effects)) == steps
    for image in (photo_batch(), _photo(2, 61, 37).float() / 255):
        params = [{} for _ in effects]
        with torch.no_grad():
            planned, stages = apply_effects(effects, params, image), apply_stages(effects, params, image)
        assert (planned - stages).abs().max() < 2e-6


def test_a_kernel_that_is_not_mirror_symmetric_ends_a_run():
    rotated, upright = Blur(1.4, 0.6, 30.0, linear=False).linear_filter(), Blur(1.4, 0.6, linear=False).linear_filter()
    assert rotated is not None and upright is not None
    assert not rotated.own.mirror_symmetric and upright.own.mirror_symmetric
    assert upright.composes_with(rotated) and not rotated.composes_with(upright)


def test_the_plan_follows_edits_to_the_stages():
    effects = [Blur(0.8, linear=False), Sharpen(1.0, 0.5)]
    image = photo_batch()
    params = [{}, {}]
    before = apply_effects(effects, params, image)
    with torch.no_grad():
        effects[1].amount.mul_(3.0)
    effects[0].linear = True  # a setting, not a tensor
    after = apply_effects(effects, params, image)
    assert (after - apply_stages(effects, params, image)).abs().max() < 2e-6
    assert (after - before).abs().max() > 0.05


def test_every_fft_path_gives_an_image_the_same_bytes_alone_as_in_a_batch():
    """The three FFT filters (a blur of radius ≥ FFT_RADIUS, the frequency response, a composed chain's spectrum
    product) bit for bit batched and alone on the CPU: a batched FFT rounds differently from single ones on some CPUs
    (MKL's AVX-512 kernels on an Intel Xeon: 4e-7 on the frequency response; this failed there before each FFT ran
    one image at a time). Not on a GPU, where the batch runs at once (``one_plane_at_a_time``)."""
    from camdegrade.functional.filtering import convolve_spectrum
    from camdegrade.functional.isp.response import frequency_response_image
    from camdegrade.functional.optics.blur import FFT_RADIUS, blur_image

    image = _photo(4, 48, 64).float() / 255
    response = FrequencyResponse.from_radial([0.1, 0.3, 0.45], [1.2, 0.8, 2.0], knots=9)
    sigma = FFT_RADIUS / 2.5  # one sigma: per-image sigmas share the batch's largest kernel radius

    def gains_of(height: int, width: int) -> torch.Tensor:
        radius = torch.fft.fftfreq(height)[:, None].abs() + torch.fft.rfftfreq(width)[None, :]
        return (1.0 + radius).to(torch.complex64)

    filters = {
        "blur": lambda x: blur_image(x, sigma),
        "response": lambda x: frequency_response_image(x, response.gains),
        "spectrum": lambda x: convolve_spectrum(x, gains_of, 5),
    }
    for name, run in filters.items():
        together = run(image)
        alone = torch.cat([run(image[i : i + 1]) for i in range(len(image))])
        assert torch.equal(together, alone), name


def test_an_empty_batch_passes_every_fft_path_and_the_frequency_response():
    """No images in, no images out, where the FFT of an empty batch is an error (MKL's; it was, before this test)."""
    from camdegrade.functional.filtering import convolve_spectrum
    from camdegrade.functional.optics.blur import FFT_RADIUS, blur_image

    empty = torch.rand(0, 3, 32, 40)
    response = FrequencyResponse.from_radial([0.1, 0.3], [1.2, 0.8], knots=9)
    assert response(empty).shape == (0, 3, 32, 40)
    assert blur_image(empty, FFT_RADIUS / 2.0).shape == (0, 3, 32, 40)
    gains = lambda height, width: torch.ones(height, width // 2 + 1, dtype=torch.complex64)  # noqa: E731
    assert convolve_spectrum(empty, gains, 3).shape == (0, 3, 32, 40)


def test_batched_equals_unbatched_and_the_input_is_untouched():
    profile = load_profile("city100-iphonex").without_randomness()  # its jitter's centre: draws nothing
    image = _photo(3, 40, 56).float() / 255
    params = [{} for _ in profile.effects]
    kept = image.clone()
    with torch.no_grad():
        together = apply_effects(profile.effects, params, image)
        alone = torch.cat([apply_effects(profile.effects, params, image[i : i + 1]) for i in range(3)])
    assert torch.equal(image, kept) and torch.equal(together, alone)
