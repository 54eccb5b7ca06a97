"""The effect contract: registry, neutral identity, config/state round trip, replayable seeded params, batching."""

from __future__ import annotations

import json
import pickle

import pytest
import torch
from torch import Tensor

import camdegrade.effects.plan as plan_module
from camdegrade.effects import (
    EFFECTS,
    JPEG,
    STAGES,
    Blur,
    ChromaticAberration,
    Color,
    ColorFilterArray,
    Denoise,
    Distortion,
    Effect,
    FrequencyResponse,
    Jitter,
    LearnedTexture,
    Misalignment,
    Noise,
    Quantization,
    Resolution,
    Sharpen,
    Tone,
    Vignetting,
    build_effect,
)
from camdegrade.effects.chain import apply_effects
from camdegrade.functional import srgb_to_linear
from effects_images import photo_batch

VOCABULARY = {
    "noise",
    "blur",
    "vignetting",
    "jpeg",
    "chromatic_aberration",
    "misalignment",
    "color",
    "tone",
    "distortion",
    "sharpen",
    "denoise",
}


def _learned_texture() -> LearnedTexture:
    """A learned texture stage as training leaves one: random hidden layers and a residual of a few levels."""
    stage = LearnedTexture.initial(8, seed=0)
    generator = torch.Generator().manual_seed(1)
    stage.conv3_weight.copy_(torch.randn(stage.conv3_weight.shape, generator=generator) * 0.005)
    stage.conv3_bias.copy_(torch.tensor([0.004, -0.002, 0.001]))
    return stage


_MATRIX = torch.tensor([[1.1, 0.05, 0.0], [0.02, 0.95, 0.03], [0.0, 0.1, 0.85]])
#: Each registered effect at a clearly visible strength, with every per-sample jitter option switched on. Every
#: effect the package registers must have an entry (tested), so the contract tests below cover it.
STRONG = {
    "blur": lambda: Blur(1.5, 0.8, 20.0, 3.0, 45.0, sigma_jitter=0.2),
    "chromatic_aberration": lambda: ChromaticAberration(0.01, -0.01),
    "cfa": lambda: ColorFilterArray("GRBG", 1.0),
    "color": lambda: Color(_MATRIX, gain_jitter=0.1),
    "distortion": lambda: Distortion(0.1, 0.02),
    "jitter": lambda: Jitter(1.0, 8.0),
    "jpeg": lambda: JPEG(40, quality_jitter=10, probability=0.7, mixture={40: 0.5, 70: 0.3, 90: 0.2}),
    "learned_texture": _learned_texture,
    "misalignment": lambda: Misalignment(0.5, -0.3, 0.4, shift_std=0.5, angle_std=0.2),
    "noise": lambda: Noise(0.01, 1e-4, 0.003, gain_jitter=0.3),
    # 32 levels through a contrast curve (a 5-bit buffer before a tone table).
    "quantization": lambda: Quantization(32, torch.linspace(0, 1, 32).pow(0.8).expand(3, 32)),
    "sharpen": lambda: Sharpen(1.2, 1.0, 0.01),
    "frequency_response": lambda: FrequencyResponse(torch.linspace(0.5, 2.0, 121).reshape(11, 11)),
    "resolution": lambda: Resolution(0.5),
    "denoise": lambda: Denoise(1.0, 0.02),
    "tone": lambda: Tone(1.2, 0.03, 0.95, 0.2, exposure_jitter=0.3),
    "vignetting": lambda: Vignetting(-0.4, 0.1),
}
#: The effects the package registers (the test-only ones of tests/profiles_for_tests.py aside).
REGISTERED = sorted(name for name, cls in EFFECTS.items() if cls.__module__.startswith("camdegrade."))


def strong(name: str) -> Effect:
    return STRONG[name]()


#: The effects that draw random values (at the strength above).
STOCHASTIC = [name for name in REGISTERED if strong(name).make_params((1, 3, 8, 8), torch.Generator())]


def _draw(effect: Effect, image: Tensor, seed: int) -> dict[str, Tensor]:
    return effect.make_params(image.shape, torch.Generator().manual_seed(seed))


def test_every_registered_effect_is_held_to_the_contract_tests() -> None:
    assert sorted(STRONG) == REGISTERED
    assert set(STOCHASTIC) >= {"noise", "jpeg", "misalignment", "tone", "color", "blur"}


def test_registry_holds_the_diagnosis_vocabulary() -> None:
    assert set(EFFECTS) >= VOCABULARY
    for name in VOCABULARY:
        cls = EFFECTS[name]
        assert cls.name == name and cls.stage in STAGES
        assert isinstance(build_effect(name), cls)
    assert {EFFECTS[name].stage for name in VOCABULARY} == set(STAGES)


@pytest.mark.parametrize("name", REGISTERED)
def test_neutral_effect_is_the_identity(name: str) -> None:
    image = photo_batch()
    effect = EFFECTS[name].neutral()
    out = effect(image, _draw(effect, image, 0))
    assert (out - image).abs().max() <= 1 / 255


@pytest.mark.parametrize("name", REGISTERED)
def test_config_and_state_round_trip(name: str) -> None:
    effect = strong(name)
    config = json.loads(json.dumps(effect.config()))
    rebuilt = type(effect).from_config(config)
    rebuilt.load_state_dict(effect.state_dict(), strict=True)
    image = photo_batch()
    params = _draw(effect, image, 3)
    assert torch.equal(rebuilt(image, params), effect(image, params))
    assert all(value.dtype.is_floating_point for value in effect.state_dict().values())
    clone = pickle.loads(pickle.dumps(effect))
    assert torch.equal(clone(image, params), effect(image, params))
    assert name in repr(effect) or type(effect).__name__ in repr(effect)


@pytest.mark.parametrize("name", REGISTERED)
def test_params_are_seeded_per_sample_and_replayable(name: str) -> None:
    effect = strong(name)
    image = photo_batch()
    first, second = _draw(effect, image, 7), _draw(effect, image, 7)
    assert first.keys() == second.keys()
    for key, value in first.items():
        assert value.shape[0] == image.shape[0] and value.device.type == "cpu", key
        assert torch.equal(value, second[key])
    out = effect(image, first)
    assert torch.equal(out, effect(image, second))
    assert out.shape == image.shape and out.dtype == image.dtype
    # A subset of the batch is replayed by indexing every param with the same index.
    index = torch.tensor([2, 0])
    subset = effect(image[index], {key: value[index] for key, value in first.items()})
    torch.testing.assert_close(subset, out[index], atol=1e-5, rtol=0)


@pytest.mark.parametrize("name", STOCHASTIC)
def test_stochastic_effects_differ_between_seeds_and_follow_the_global_rng(name: str) -> None:
    effect = strong(name)
    image = photo_batch()
    assert not torch.equal(effect(image, _draw(effect, image, 1)), effect(image, _draw(effect, image, 2)))
    torch.manual_seed(5)
    global_first = effect(image)
    torch.manual_seed(5)
    assert torch.equal(effect(image), global_first)


@pytest.mark.parametrize("name", REGISTERED)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_forward_keeps_dtype_and_does_not_modify_input(name: str, dtype: torch.dtype) -> None:
    effect = strong(name)
    image = photo_batch(24, 32).to(dtype)
    before, version = image.clone(), image._version
    out = effect(image, _draw(effect, image, 0))
    assert out.dtype == dtype and out.shape == image.shape
    assert image._version == version and torch.equal(image, before)


def test_jitter_varies_samples_and_jpeg_probability_skips_some() -> None:
    image = photo_batch()[:1].expand(6, -1, -1, -1)
    tone = strong("tone")
    out = tone(image, _draw(tone, image, 0))
    assert len({round(float(sample.mean()), 4) for sample in out}) == 6
    jpeg = JPEG(30, probability=0.5)
    params = _draw(jpeg, image, 4)
    out = jpeg(image, params)
    untouched = [torch.equal(out[i], image[i]) for i in range(6)]
    assert untouched == (~params["apply"]).tolist() and any(untouched) and not all(untouched)


def test_noise_gain_jitter_scales_noise() -> None:
    image = torch.full((2, 3, 64, 64), 0.4)
    noise = Noise(0.01, 1e-4, gain_jitter=0.5)
    params = _draw(noise, image, 0)
    params["gain"] = torch.tensor([0.5, 2.0])
    out = noise(image, params)
    assert out[1].std() > 1.8 * out[0].std()  # variance a·g·I + b·g²: the std ratio is between 2 and 4


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("name", REGISTERED)
def test_cuda_image_with_params_moved_to_it(name: str) -> None:
    effect = strong(name)
    image = photo_batch()
    params = _draw(effect, image, 0)
    on_cpu = effect(image, params)
    on_gpu = effect.cuda()(image.cuda(), {key: value.cuda() for key, value in params.items()})
    assert on_gpu.device.type == "cuda"
    # JPEG: no coefficient rounds otherwise (that would move a pixel by a level or more); an H200 leaves one float32
    # ulp (6e-8) on 40 % of the pixels (torch 2.11).
    torch.testing.assert_close(on_gpu.cpu(), on_cpu, atol=2e-4 if name != "jpeg" else 1e-6, rtol=0)


def test_constructor_errors_name_the_argument() -> None:
    with pytest.raises(ValueError, match=r"quality must be an integer from 1 to 100, got quality=0"):
        JPEG(0)
    with pytest.raises(ValueError, match=r"probability must be in \[0, 1\], got probability=1.5"):
        JPEG(50, probability=1.5)
    with pytest.raises(ValueError, match="quality_jitter must be a non-negative integer"):
        JPEG(50, quality_jitter=-1)
    with pytest.raises(ValueError, match=r"sigma_x must be non-negative, got sigma_x=-1\.0"):
        Blur(-1.0)
    with pytest.raises(ValueError, match="white must be greater than black"):
        Tone(black=0.6, white=0.5)
    with pytest.raises(ValueError, match=r"matrix must have shape \(3, 3\), got shape \(2, 2\)"):
        Color(torch.eye(2))
    with pytest.raises(ValueError, match=r"a must be a number or have shape \(3,\), got shape \(2,\)"):
        Noise(a=[0.1, 0.2])
    with pytest.raises(ValueError, match="shift_std must be a finite non-negative number"):
        Misalignment(shift_std=-1.0)
    with pytest.raises(ValueError, match=r"shape must be \(N, 3, H, W\), got shape \(3, 8, 8\)"):
        Noise(0.01).make_params((3, 8, 8))
    with pytest.raises(NotImplementedError, match="has no fitter"):
        Effect.fit(torch.zeros(1, 3, 4, 4), torch.zeros(1, 3, 4, 4))


def test_profile_with_an_effect_chain_round_trips(tmp_path) -> None:
    profile_module = pytest.importorskip("camdegrade.profile")
    chain = [strong(name) for name in ("misalignment", "vignetting", "blur", "noise", "color", "tone", "jpeg")]
    profile = profile_module.CameraProfile(None, chain, name="virtual")
    path = profile.save(tmp_path / "virtual.safetensors")
    loaded = profile_module.load_profile(path)
    assert [effect.name for effect in loaded.effects] == [effect.name for effect in chain]
    image = photo_batch()
    expected = profile(image, profile.make_params(image.shape, torch.Generator().manual_seed(11)))
    replayed = loaded(image, loaded.make_params(image.shape, torch.Generator().manual_seed(11)))
    assert torch.equal(replayed, expected)


def _encoded_variants() -> list[Effect]:
    """Every effect at strength, plus the forms whose encodings differ (sRGB-domain stages, tone without exposure)."""
    return [strong(name) for name in REGISTERED] + [
        Blur(1.0),
        Blur(1.2, linear=False),
        Noise(0.01, 1e-4, linear=False),
        Noise(0.004, 0.0, 0.0),
        Color(torch.eye(3) * 0.9, linear=False),
        Tone(1.3, 0.02, 0.9),
        *[effect for examples in LINEAR_EXAMPLES.values() for effect in examples],
    ]


#: Forms of the effects that are linear shift-invariant filters (a chain's plan composes them): besides the strong
#: forms above (coring, jitter), which are not.
LINEAR_EXAMPLES = {
    "blur": [Blur(1.4, 0.6, 30.0, 3.0, 20.0), Blur(0.9, linear=False)],
    "sharpen": [Sharpen(1.0, 0.8), Sharpen(0.8, 1.5, luma=False), Sharpen(1.0, 0.0, 0.02)],
    "denoise": [Denoise(1.0, 0.0)],
    "frequency_response": [FrequencyResponse(torch.linspace(0.5, 2.0, 121).reshape(11, 11))],
}


def _linear_candidates(name: str) -> list[Effect]:
    centre = strong(name).without_randomness()
    return [
        strong(name),
        EFFECTS[name].neutral(),
        *([centre] if centre is not None else []),
        *LINEAR_EXAMPLES.get(name, []),
    ]


@pytest.mark.parametrize("name", REGISTERED)
def test_a_stated_linear_filter_is_the_stage(name: str) -> None:
    """What :meth:`Effect.linear_filter` states is the stage: it draws nothing, works in the stage's encoding, and
    running the filter gives the stage's output (within float rounding)."""
    image = photo_batch()
    for effect in _linear_candidates(name):
        stated = effect.linear_filter()
        if stated is None:
            continue
        assert effect.make_params(image.shape, torch.Generator().manual_seed(0)) == {}
        assert effect.encodings() == (stated.encoding, stated.encoding)
        encoded = srgb_to_linear(image) if stated.encoding == "linear" else image.clone()
        with torch.no_grad():
            expected = effect.forward_encoded(encoded.clone(), {})
            assert (stated.run_(encoded.clone()) - expected).abs().max() < 2e-6, effect


def test_the_linear_stages_state_their_filters_and_the_others_none() -> None:
    stating = {name for name in REGISTERED if any(e.linear_filter() is not None for e in _linear_candidates(name))}
    # jitter's centre (its mean over the field) is a Gaussian blur: that states a filter, the jitter itself does not
    assert stating == {"blur", "sharpen", "denoise", "frequency_response", "jitter"}
    assert strong("jitter").linear_filter() is None
    assert strong("sharpen").linear_filter() is None and strong("denoise").linear_filter() is None  # coring
    assert strong("blur").linear_filter() is None  # a PSF of its own for every sample


@pytest.mark.parametrize("effect", _encoded_variants(), ids=lambda effect: f"{effect.name}({effect.extra_repr()[:40]})")
def test_encoded_forward_in_a_chain_equals_forward(effect: Effect) -> None:
    image = photo_batch()
    params = _draw(effect, image, seed=3)
    expected = effect(image, params)
    before = image.clone()
    with torch.no_grad():
        chained = apply_effects([effect], [params], image)
    assert torch.equal(image, before)
    # JPEG re-encodes 8-bit values, where a float-rounding difference can flip one level.
    tolerance = 1.5 / 255 if effect.name == "jpeg" else 2e-6
    assert (chained - expected).abs().max() <= tolerance


def test_chain_shares_one_srgb_decode_and_matches_stage_by_stage() -> None:
    stages = [strong(name) for name in ("vignetting", "blur", "noise", "color", "tone")]
    image = photo_batch()
    params = [_draw(stage, image, seed=index) for index, stage in enumerate(stages)]
    expected = image
    for stage, stage_params in zip(stages, params, strict=True):
        expected = stage(expected, stage_params)
    decodes = []
    original = plan_module.srgb_to_linear_
    plan_module.srgb_to_linear_ = lambda x: decodes.append(1) or original(x)  # type: ignore[assignment]
    try:
        with torch.no_grad():
            chained = apply_effects(stages, params, image)
    finally:
        plan_module.srgb_to_linear_ = original  # type: ignore[assignment]
    assert len(decodes) == 1
    assert (chained - expected).abs().max() <= 2e-6
    with_graph = apply_effects(stages, params, image.clone().requires_grad_())
    assert with_graph.requires_grad
    assert (with_graph.detach() - expected).abs().max() <= 2e-6


# --- how an effect moves positions (targets follow it) -------------------------------------------------------------

_DOTS = [(-14.0, -9.0), (0.0, 0.0), (11.5, 7.0), (-3.0, 12.5)]


def _dot_image(x: float, y: float, height: int = 48, width: int = 64) -> Tensor:
    """A grey frame with a small Gaussian dot centred at centred pixel coordinates ``(x, y)``."""
    ys = torch.arange(height, dtype=torch.float64) + 0.5 - height / 2
    xs = torch.arange(width, dtype=torch.float64) + 0.5 - width / 2
    dot = torch.exp(-((xs[None] - x) ** 2 + (ys[:, None] - y) ** 2) / (2 * 1.5**2))
    return (0.2 + 0.6 * dot).float().expand(1, 3, height, width).clone()


def _dot_centre(effect: Effect, x: float, y: float, params: dict[str, Tensor], near: tuple[float, float]) -> Tensor:
    """Where the dot lands: the centroid of the effect's output minus its output on the bare frame (same params),
    within 6 pixels of ``near``."""
    image = _dot_image(x, y)
    bare = torch.full_like(image, 0.2)
    change = (effect(image, params) - effect(bare, params)).mean(1)[0].double()
    height, width = change.shape
    ys = torch.arange(height, dtype=torch.float64)[:, None] + 0.5 - height / 2
    xs = torch.arange(width, dtype=torch.float64)[None] + 0.5 - width / 2
    window = ((xs - near[0]).abs() <= 6) & ((ys - near[1]).abs() <= 6)
    weight = change.clamp_min(0) * window
    return torch.stack(((weight * xs).sum() / weight.sum(), (weight * ys).sum() / weight.sum()))


@pytest.mark.parametrize("name", REGISTERED)
def test_every_effect_moves_positions_as_it_moves_the_image(name: str) -> None:
    """An effect that moves pixels says where (its moved_points lands a dot where its image does, and
    source_points inverts it); every other effect leaves a dot where it was and maps positions to themselves."""
    effect = strong(name)
    params = effect.make_params((1, 3, 48, 64), torch.Generator().manual_seed(1))
    x = torch.tensor([[p[0] for p in _DOTS]], dtype=torch.float64)
    y = torch.tensor([[p[1] for p in _DOTS]], dtype=torch.float64)
    moved_x, moved_y = effect.moved_points(x, y, (48, 64), params)
    back_x, back_y = effect.source_points(moved_x, moved_y, (48, 64), params)
    torch.testing.assert_close(torch.stack((back_x, back_y)), torch.stack((x, y)), atol=1e-6, rtol=0)
    if not effect.moves_pixels:
        assert torch.equal(moved_x, x) and torch.equal(moved_y, y)
        assert type(effect).source_points is Effect.source_points and type(effect).moved_points is Effect.moved_points
    for index, (dot_x, dot_y) in enumerate(_DOTS):
        expected = (float(moved_x[0, index]), float(moved_y[0, index]))
        found = _dot_centre(effect, dot_x, dot_y, params, near=expected)
        assert (found - torch.tensor(expected, dtype=torch.float64)).abs().max() < 0.3, (name, _DOTS[index], found)


def test_moving_effects_are_the_warps() -> None:
    assert {name for name in REGISTERED if EFFECTS[name].moves_pixels} == {"distortion", "jitter", "misalignment"}


def test_the_dot_check_can_fail() -> None:
    """A stage claiming to stay put while it shifts the image is caught by the dot measurement."""
    shifted = Misalignment(1.0, 0.0)
    found = _dot_centre(shifted, 0.0, 0.0, {}, near=(0.0, 0.0))
    assert abs(float(found[0]) - 1.0) < 0.1
