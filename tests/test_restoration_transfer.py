"""The restoration-transfer bench's own parts (bench/aligned_scoring.py, bench/restoration_rows.py,
bench/bench_restoration_transfer.py), on synthetic images: the alignment-tolerant PSNR does not charge a sub-pixel
shift, the blur + colour map fit recovers a known map, and the closure is measured from the colour map to real."""

from __future__ import annotations

import math

import pytest
import torch

from conftest import load_script

scoring = load_script("bench/aligned_scoring.py", "camdegrade_aligned_scoring")
GRID = scoring.TileGrid(tile=48, margin=8, radius=3)


def periodic_texture(size: int, seed: int, cutoff: float = 0.12) -> torch.Tensor:
    """A ``(3, size, size)`` texture in about [0.1, 0.9] that is periodic and band-limited (Gaussian spectrum of std
    ``cutoff`` cycles/px), so that a Fourier shift moves it exactly."""
    generator = torch.Generator().manual_seed(seed)
    spectrum = torch.randn(3, size, size, 2, generator=generator, dtype=torch.float64)
    radius = torch.fft.fftfreq(size)[:, None] ** 2 + torch.fft.fftfreq(size)[None, :] ** 2
    envelope = torch.exp(-radius / (2 * cutoff**2))
    texture = torch.fft.ifft2(torch.view_as_complex(spectrum) * envelope).real
    texture = texture - texture.mean((-2, -1), keepdim=True)
    return (0.5 + 0.4 * texture / texture.abs().amax()).float()


def fourier_shift(image: torch.Tensor, dy: float, dx: float) -> torch.Tensor:
    """``image`` moved down by ``dy`` and right by ``dx`` pixels (periodically)."""
    height, width = image.shape[-2:]
    phase = torch.fft.fftfreq(height)[:, None] * dy + torch.fft.fftfreq(width)[None, :] * dx
    return torch.fft.ifft2(torch.fft.fft2(image.double()) * torch.exp(-2j * math.pi * phase)).real.float()


def fourier_blur(image: torch.Tensor, sigma: float) -> torch.Tensor:
    """``image`` blurred by a periodic Gaussian of ``sigma`` pixels."""
    height, width = image.shape[-2:]
    radius = torch.fft.fftfreq(height)[:, None] ** 2 + torch.fft.fftfreq(width)[None, :] ** 2
    return torch.fft.ifft2(torch.fft.fft2(image.double()) * torch.exp(-2 * math.pi**2 * sigma**2 * radius)).real.float()


def plain_psnr(image: torch.Tensor, reference: torch.Tensor) -> float:
    return -10 * math.log10(float((image - reference).pow(2).mean()))


def test_a_sub_pixel_shift_of_the_reference_is_found_and_not_charged() -> None:
    reference = periodic_texture(160, seed=0)
    moved = fourier_shift(reference, 0.3, -0.45)
    aligned = scoring.align_tiles(moved, reference, GRID)
    assert plain_psnr(moved, reference) < 34
    assert aligned.psnr_db > 55
    # the tile shows the image at position + shift: moved(y + 0.3, x - 0.45) = reference(y, x)
    assert torch.allclose(aligned.shifts.mean(0), torch.tensor([0.3, -0.45]), atol=0.04)


@pytest.mark.parametrize(("dy", "dx"), [(0.5, 0.0), (-0.8, 0.6), (1.7, -2.2)])
def test_a_shifted_restoration_scores_as_the_unshifted_one(dy: float, dx: float) -> None:
    """A soft, darker image (30.7 dB) scores the same against the reference whether it is moved by a sub-pixel
    shift or not, within 0.1 dB (Lanczos-3's response is not perfectly flat: moved, it scores 0.06-0.08 dB
    better); unaligned, the shift costs it 1.5 to 10 dB."""
    reference = periodic_texture(160, seed=1)
    degraded = 0.98 * fourier_blur(reference, 1.0)
    unmoved = scoring.aligned_psnr(degraded, reference, GRID)
    moved = fourier_shift(degraded, dy, dx)
    assert plain_psnr(moved, reference) < unmoved - 1
    assert scoring.aligned_psnr(moved, reference, GRID) == pytest.approx(unmoved, abs=0.1)


def test_an_error_that_no_shift_explains_is_scored_in_full() -> None:
    """A brightness offset (which interpolation leaves as it is) scores its own PSNR, moved or not."""
    reference = periodic_texture(160, seed=3)
    for offset in (0.01, 0.03):
        moved = fourier_shift(reference + offset, 0.4, -1.3)
        assert scoring.aligned_psnr(moved, reference, GRID) == pytest.approx(-20 * math.log10(offset), abs=0.05)


def test_the_tiles_stay_inside_the_margin_and_bad_shapes_are_refused() -> None:
    assert GRID.origins(120, 170) == [(12, 13), (12, 61), (12, 109), (60, 13), (60, 61), (60, 109)]
    with pytest.raises(ValueError, match="margin must be at least radius \\+ 4"):
        scoring.TileGrid(tile=48, margin=6, radius=3)
    with pytest.raises(ValueError, match="at least 64 px a side"):
        GRID.origins(60, 200)
    with pytest.raises(ValueError, match="image and reference must be"):
        scoring.align_tiles(torch.zeros(3, 80, 80), torch.zeros(3, 80, 81), GRID)


def test_lanczos_taps_sum_to_one_and_an_integer_shift_reads_one_pixel() -> None:
    taps = scoring.lanczos_taps(torch.tensor([0.0, 2.0, 0.25], dtype=torch.float64), 4)
    assert torch.allclose(taps.sum(-1), torch.ones(3, dtype=torch.float64))
    assert torch.allclose(taps[1], torch.nn.functional.one_hot(torch.tensor(6), 9).double(), atol=1e-12)


def test_the_colour_map_fit_recovers_a_known_blur_and_map() -> None:
    rows = load_script("bench/restoration_rows.py", "camdegrade_restoration_rows")
    matrix = torch.tensor([[0.9, 0.05, 0.0, 0.03], [0.02, 1.05, -0.04, -0.02], [0.0, 0.1, 0.8, 0.05]])
    known = rows.ColourMap(1.4, matrix)
    cleans = [periodic_texture(128, seed, cutoff=0.15) for seed in range(3)]
    fitted = rows.fit_colour_map(cleans, [known(clean) for clean in cleans])
    assert fitted.sigma == pytest.approx(1.4, rel=0.1)
    assert torch.allclose(fitted.matrix, matrix, atol=0.02)


#: Two seeds' PSNR (dB) on two held-out images per row, and the captures' own: the closure's worked example.
CAPTURE_PSNR = [20.0, 30.0]
TWO_SEEDS_PSNR = {
    "real": [[21.0, 31.0], [21.2, 31.2]],
    "colour_map": [[19.5, 29.5], [19.7, 29.7]],
    "built_in": [[20.5, 30.5], [20.4, 30.4]],
}


def _bench():
    return load_script("bench/bench_restoration_transfer.py", "camdegrade_bench_restoration_transfer")


def test_the_closure_runs_from_the_colour_map_to_real() -> None:
    bench, capture, psnr = _bench(), CAPTURE_PSNR, TWO_SEEDS_PSNR
    summary = bench.summarise(psnr, capture, capture)
    assert summary["mean"]["real"] == pytest.approx(1.1)
    assert summary["spread"]["built_in"] == pytest.approx(0.1)
    assert summary["closure"] == pytest.approx({"real": 1.0, "colour_map": 0.0, "built_in": 0.85 / 1.5})
    assert summary["closure_per_seed"]["built_in"] == pytest.approx([1.0 / 1.5, 0.7 / 1.5])


def test_runs_of_one_seed_each_combine_into_the_summary_of_all_seeds(tmp_path) -> None:
    bench, capture, psnr = _bench(), CAPTURE_PSNR, TWO_SEEDS_PSNR
    paths = []
    for seed in (0, 1):
        record = {
            "psnr_db": {name: [rows[seed]] for name, rows in psnr.items()},
            "capture_psnr_db": capture,
            "summary": {"capture_unaligned_psnr_db": 19.0},
            "seeds": [seed],
            "held_out": ["056", "057"],
            "restorer": {"steps": 10},
            "camdegrade": "x",
            "torch": "y",
            "wall_seconds": 1.0,
            "cpu_seconds": 2.0,
        }
        paths.append(tmp_path / f"seed{seed}.json")
        paths[-1].write_text(bench.json.dumps(record))
    combined = bench.combine(paths)
    assert combined["seeds"] == [0, 1]
    assert combined["summary"]["closure"] == pytest.approx({"real": 1.0, "colour_map": 0.0, "built_in": 0.85 / 1.5})
    assert combined["summary"]["closure_per_seed"]["built_in"] == pytest.approx([1.0 / 1.5, 0.7 / 1.5])
    with pytest.raises(ValueError, match="a seed is in two runs"):
        bench.combine([paths[0], paths[0]])
    other = bench.json.loads(paths[1].read_text())
    other["restorer"] = {"steps": 20}
    paths[1].write_text(bench.json.dumps(other))
    with pytest.raises(ValueError, match="restorer differs"):
        bench.combine(paths)
