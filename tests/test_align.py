from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from camdegrade.pairs.align import AlignmentResult, align_pair, apply_shift, estimate_shift, format_shifts, register

skimage_data = pytest.importorskip("skimage.data")
ndimage = pytest.importorskip("scipy.ndimage")

TOLERANCE = 0.25  # px, from the issue
MARGIN = 16
SIZE = 176


@pytest.fixture(autouse=True, scope="module")
def _single_thread():
    # These images are tiny: intra-op threads only add overhead, and on a busy CI box their spin-waits cost 40x.
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def natural(name: str) -> np.ndarray:
    """A float64 (H, W, 3) crop in [0, 1] of a skimage sample image, with a margin for shifting."""
    top, left = {"astronaut": (30, 150), "chelsea": (40, 150), "coffee": (90, 200)}[name]
    image = getattr(skimage_data, name)()[top : top + SIZE + 2 * MARGIN, left : left + SIZE + 2 * MARGIN]
    return image.astype(np.float64) / 255.0


def capture(image: np.ndarray, dy: float, dx: float, seed: int, *, degrade: bool = True) -> torch.Tensor:
    """Move ``image`` by (dy, dx) with scipy's cubic spline (independent of the code under test), then blur it,
    add a colour cast and noise, and quantise to uint8, like a cheap camera would."""
    moved = np.stack([ndimage.shift(image[..., c], (dy, dx), order=3, mode="reflect") for c in range(3)], -1)
    if degrade:
        moved = np.stack([ndimage.gaussian_filter(moved[..., c], 1.2) for c in range(3)], -1)
        moved = moved * np.array([1.08, 1.0, 0.85]) + 0.03
        moved = moved + np.random.default_rng(seed).normal(0.0, 6 / 255, moved.shape)
    return to_uint8(moved[MARGIN:-MARGIN, MARGIN:-MARGIN])


def to_uint8(image: np.ndarray) -> torch.Tensor:
    pixels = np.clip(np.round(image * 255.0), 0, 255).astype(np.uint8)
    return torch.from_numpy(pixels).permute(2, 0, 1).contiguous()


def reference(image: np.ndarray) -> torch.Tensor:
    return to_uint8(image[MARGIN:-MARGIN, MARGIN:-MARGIN])


SHIFTS = [(1.3, -2.7), (0.25, 0.5), (-0.5, 0.75), (3.0, -5.0), (-7.0, 2.0), (4.6, 6.1)]


@pytest.mark.parametrize("name", ["astronaut", "chelsea", "coffee"])
@pytest.mark.parametrize("shift", SHIFTS, ids=str)
def test_estimate_shift_recovers_known_shifts_of_degraded_captures(name: str, shift: tuple[float, float]) -> None:
    image = natural(name)

    found = estimate_shift(reference(image), capture(image, *shift, seed=SHIFTS.index(shift)))

    error = max(abs(found[0] - shift[0]), abs(found[1] - shift[1]))
    assert error < TOLERANCE, f"{name}: expected {shift}, found {found}"


@pytest.mark.parametrize("name", ["astronaut", "coffee"])
def test_zero_shift_is_found_as_zero(name: str) -> None:
    image = natural(name)

    dy, dx = estimate_shift(reference(image), capture(image, 0.0, 0.0, seed=0))

    assert abs(dy) < 0.05 and abs(dx) < 0.05


def test_estimate_shift_accepts_float_grayscale_and_mixed_inputs() -> None:
    image = natural("chelsea")
    ref, mov = reference(image), capture(image, 1.3, -2.7, seed=1, degrade=False)
    expected = (1.3, -2.7)

    gray = estimate_shift(ref.float().mean(0), mov.float().mean(0))
    floats = estimate_shift(ref.float() / 255, mov.double() / 255)
    mixed = estimate_shift(ref, mov[:1].float())

    for found in (gray, floats, mixed):
        assert max(abs(found[0] - expected[0]), abs(found[1] - expected[1])) < 0.1


def test_register_scores_agreement() -> None:
    image = natural("astronaut")
    ref = reference(image)

    same = register(ref, capture(image, 2.5, -1.5, seed=2))
    noise = register(
        ref, torch.randint(0, 256, ref.shape, dtype=torch.uint8, generator=torch.Generator().manual_seed(0))
    )

    assert isinstance(same, AlignmentResult) and same.score > 0.9
    assert abs(noise.score) < 0.2
    assert str(same).startswith("dy=+2.")


def test_apply_shift_matches_an_independent_interpolator_and_is_exact_for_integers() -> None:
    image = np.stack([ndimage.gaussian_filter(natural("coffee")[..., c], 1.5) for c in range(3)], -1)
    tensor = torch.from_numpy(image).permute(2, 0, 1).contiguous()

    moved = apply_shift(tensor, 1.3, -2.7)
    expected = np.stack([ndimage.shift(image[..., c], (1.3, -2.7), order=5, mode="reflect") for c in range(3)])
    interior = (slice(None), slice(8, -8), slice(8, -8))
    assert np.abs(moved.numpy()[interior] - expected[interior]).max() < 0.01

    whole = apply_shift(tensor, 3, -2)
    assert torch.allclose(whole[:, 3:, :-2], tensor[:, :-3, 2:], atol=1e-6)


@pytest.mark.parametrize("dtype", [torch.uint8, torch.float32, torch.float64])
def test_apply_shift_keeps_shape_dtype_and_input(dtype: torch.dtype) -> None:
    image = torch.randint(0, 256, (2, 3, 24, 30), generator=torch.Generator().manual_seed(0)).to(dtype)
    before = image.clone()

    moved = apply_shift(image, 0.5, -1.25)

    assert moved.shape == image.shape and moved.dtype == dtype
    assert torch.equal(image, before)
    assert torch.equal(apply_shift(image, 0.0, 0.0), image)


def test_apply_shift_refuses_bad_input() -> None:
    with pytest.raises(TypeError, match=r"dtype torch\.int32"):
        apply_shift(torch.zeros(3, 8, 8, dtype=torch.int32), 1, 1)
    with pytest.raises(ValueError, match="smaller than the image size"):
        apply_shift(torch.zeros(3, 8, 8), 9, 0)


@pytest.mark.parametrize("move", ["clean", "captured"])
def test_align_pair_undoes_the_shift_and_crops_the_invalid_border(move: str) -> None:
    image = natural("astronaut")
    clean, captured = reference(image), capture(image, 1.3, -2.7, seed=3, degrade=False)

    clean_out, captured_out, result = align_pair(clean, captured, move=move)  # type: ignore[arg-type]

    assert clean_out.shape == captured_out.shape == (3, SIZE - 2, SIZE - 3)
    assert clean_out.dtype == captured_out.dtype == torch.uint8
    assert abs(result.dy - 1.3) < 0.1 and abs(result.dx + 2.7) < 0.1
    residual = estimate_shift(clean_out, captured_out)
    assert math.hypot(*residual) < 0.1
    untouched = captured if move == "clean" else clean
    kept = captured_out if move == "clean" else clean_out
    assert any(
        torch.equal(kept, untouched[:, r : r + kept.shape[1], c : c + kept.shape[2]]) for r in (0, 2) for c in (0, 3)
    )
    # aligned images agree far better than the raw pair
    before = (clean.float() - captured.float()).abs().mean()
    after = (clean_out.float() - captured_out.float()).abs().mean()
    assert after < 0.3 * before


def test_estimate_shift_refuses_mismatched_or_malformed_images() -> None:
    with pytest.raises(ValueError, match="same height and width"):
        estimate_shift(torch.zeros(3, 32, 32), torch.zeros(3, 32, 30))
    with pytest.raises(ValueError, match=r"shape \(3, H, W\)"):
        estimate_shift(torch.zeros(4, 32, 32), torch.zeros(4, 32, 32))
    with pytest.raises(TypeError, match=r"moving must be a torch\.Tensor"):
        estimate_shift(torch.zeros(32, 32), np.zeros((32, 32)))  # type: ignore[arg-type]


def test_format_shifts_lists_every_pair() -> None:
    table = format_shifts({"001": AlignmentResult(0.12, -1.5, 0.97), "002": AlignmentResult(-2.0, 0.0, 0.8)})

    assert "001" in table and "+0.12" in table and "-1.50" in table
    assert "largest shift 2.00 px" in table and "lowest score 0.800" in table
    assert format_shifts({}) == "no pairs registered"


@pytest.mark.realdata
def test_city100_pairs_are_already_registered_to_a_fraction_of_a_pixel(real_pairs_dir: Path) -> None:
    from camdegrade.io import read_image

    folder = real_pairs_dir / "city100_camera_lens_sr" / "City100_iPhoneX"
    clean, captured = read_image(folder / "001H.PNG"), read_image(folder / "001L.PNG")

    result = register(clean, captured)

    assert math.hypot(result.dy, result.dx) < 0.5 and result.score > 0.8
