"""The foreign cameras themselves (``tests/foreign_cameras``): written without camdegrade, deterministic, and each
doing what its docstring says. What camdegrade's fit and diagnosis make of them is the bench's business
(``bench/bench_foreign_fit.py``, ``bench/bench_foreign_diagnosis.py``), not these tests'."""

from __future__ import annotations

import ast
import io
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy import fft, ndimage

from foreign_cameras import BASES, CAMERAS, CHECK_BASES, SCENARIOS, camera, scenes
from foreign_cameras.codec import jpeg_bytes
from foreign_cameras.demosaic import DEMOSAICERS
from foreign_cameras.sensor import mosaic
from foreign_cameras.stages import Cos4Vignetting, Misalign, ToneLUT

PACKAGE = Path(__file__).parent / "foreign_cameras"
#: What the cameras may import besides the standard library: numpy, scipy and PIL (and their own package).
ALLOWED = {"numpy", "scipy", "PIL", "foreign_cameras"}
#: scikit-image gives the clean scenes its sample photos; no camera step uses it.
ALLOWED_IN = {"scenes.py": {"skimage"}}


def imported_roots(source: str) -> set[str]:
    """The top-level package of every import in ``source`` (relative imports as ``foreign_cameras``)."""
    roots = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            roots.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            roots.add("foreign_cameras" if node.level else (node.module or "").split(".")[0])
    return roots


def forbidden_imports(source: str, file_name: str) -> set[str]:
    allowed = ALLOWED | ALLOWED_IN.get(file_name, set()) | set(sys.stdlib_module_names)
    return imported_roots(source) - allowed


@pytest.mark.parametrize("path", sorted(PACKAGE.glob("*.py")), ids=lambda path: path.name)
def test_the_cameras_import_numpy_scipy_and_pil_only(path: Path) -> None:
    assert forbidden_imports(path.read_text(), path.name) == set()


def test_the_import_rule_can_fail() -> None:
    source = "import numpy as np\nfrom camdegrade.effects import Blur\nimport torch.nn\nfrom . import tone\n"
    assert forbidden_imports(source, "optics.py") == {"camdegrade", "torch"}
    assert forbidden_imports("import skimage.data\n", "optics.py") == {"skimage"}
    assert forbidden_imports("import skimage.data\n", "scenes.py") == set()


@pytest.fixture(scope="module")
def clean() -> list[np.ndarray]:
    return scenes(4, 64, seed=5)


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_same_seed_same_bytes_and_another_seed_other_bytes(name: str, clean: list[np.ndarray]) -> None:
    first = [camera(name)(image, seed=(3, index)) for index, image in enumerate(clean)]
    again = [camera(name)(image, seed=(3, index)) for index, image in enumerate(clean)]
    other = [camera(name)(image, seed=(4, index)) for index, image in enumerate(clean)]
    assert all(a.tobytes() == b.tobytes() for a, b in zip(first, again, strict=True))
    assert any(a.tobytes() != b.tobytes() for a, b in zip(first, other, strict=True))
    assert [image.tobytes() for image in scenes(4, 64, seed=5)] == [image.tobytes() for image in clean]


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_any_size_in_the_same_size_and_dtype_out(name: str) -> None:
    image = scenes(1, 97, seed=1)[0][:, :83]
    out = camera(name)(image, seed=0)
    assert out.shape == image.shape and out.dtype == np.uint8
    assert np.abs(out.astype(float) - image).mean() > 2.0  # every camera changes the image


def test_a_float_image_is_refused_with_its_name() -> None:
    with pytest.raises(ValueError, match=r"image must be a uint8 numpy array of shape \(H, W, 3\), got ndarray float"):
        camera("webcam")(np.zeros((8, 8, 3)), seed=0)


def _phase_variances(image: np.ndarray) -> np.ndarray:
    """(channel, y mod 2, x mod 2): the variance of the high-passed image at each Bayer phase."""
    x = image.astype(np.float64)
    residual = x - ndimage.uniform_filter(x, (5, 5, 1), mode="mirror")
    return np.array([[[residual[i::2, j::2, c].var() for j in (0, 1)] for i in (0, 1)] for c in range(3)])


def test_the_phone_keeps_its_rggb_demosaic_phase_in_the_noise() -> None:
    """On flat grey, each colour is noisiest at the sites that sampled it (red at (0, 0), blue at (1, 1)) and
    smoother where the demosaicer interpolated it."""
    grey = np.full((128, 128, 3), 110, np.uint8)
    variance = np.mean([_phase_variances(camera("phone")(grey, seed)) for seed in range(3)], axis=0)
    assert variance[0, 0, 0] > 1.5 * variance[0].mean() and variance[0].argmax() == 0
    assert variance[2, 1, 1] > 1.4 * variance[2].mean() and variance[2].argmax() == 3


@pytest.mark.parametrize("method", sorted(DEMOSAICERS))
@pytest.mark.parametrize(("pattern", "green_sites"), [("RGGB", (1, 2)), ("GRBG", (0, 3))])
def test_demosaicers_interpolate_at_the_pattern_phase(method: str, pattern: str, green_sites: tuple[int, int]) -> None:
    """White noise through the mosaic and back: a bilinear demosaicer's green is 4× noisier where it was sampled
    than where it averaged four neighbours; Hamilton-Adams keeps the sampled sites noisier too. A flat image
    comes back exactly."""
    rng = np.random.default_rng(0)
    noise = 0.5 + 0.05 * rng.standard_normal((128, 128, 3))
    green = _phase_variances(DEMOSAICERS[method](mosaic(noise, pattern), pattern))[1].ravel()
    others = [index for index in range(4) if index not in green_sites]
    ratio = green[list(green_sites)].mean() / green[others].mean()
    assert ratio > (3.0 if method == "bilinear" else 1.05), ratio
    flat = np.full((16, 16, 3), 0.3)
    np.testing.assert_allclose(DEMOSAICERS[method](mosaic(flat, pattern), pattern), flat, atol=1e-12)


def test_the_phone_skips_the_output_levels_its_table_cannot_reach() -> None:
    """Tone as an 8-bit table on 8-bit values: every output value is one of the table's, and the codes it skips
    (where it is steeper than 1) never appear, even on a smooth ramp."""
    ramp = np.tile(np.linspace(20, 235, 256)[None, :, None], (64, 1, 3)).round().astype(np.uint8)
    out = camera("phone")(ramp, seed=0)
    table = next(stage for stage in camera("phone").stages if isinstance(stage, ToneLUT)).table()
    reachable = set(table.tolist())
    skipped = set(range(int(out.min()), int(out.max()) + 1)) - reachable
    assert len(skipped) >= 10
    assert set(np.unique(out).tolist()) <= reachable


def _lattice_distance(image: np.ndarray, table: np.ndarray) -> float:
    """Mean distance of the luma's 8×8 DCT coefficients (JPEG's level shift and transform) from the multiples of
    ``table`` (natural order), over the coefficients whose step is at least 10 levels (the decoder's rounding to 8
    bits moves a coefficient by about 0.3) and that are not rounded to zero (flat content puts any image near the
    lattice's zero): near 0 for a decoded JPEG of that table, 0.25 for no JPEG."""
    rgb = image.astype(np.float64)
    luma = rgb @ np.array([0.299, 0.587, 0.114]) - 128.0
    height, width = (luma.shape[0] // 8) * 8, (luma.shape[1] // 8) * 8
    blocks = luma[:height, :width].reshape(height // 8, 8, width // 8, 8).transpose(0, 2, 1, 3)
    ratio = fft.dctn(blocks, axes=(2, 3), norm="ortho") / table.reshape(8, 8)
    distance = np.abs(ratio - np.round(ratio))
    counted = (table.reshape(8, 8) >= 10) & (np.abs(ratio) > 0.5)
    return float(distance[counted].mean())


def test_a_jpeg_at_the_end_puts_the_luma_on_its_quantization_lattice() -> None:
    with Image.open(io.BytesIO(jpeg_bytes(np.zeros((8, 8, 3)), 75))) as probe:
        table = np.asarray(probe.quantization[0], dtype=np.float64)
    image = scenes(2, 128, seed=2)[0]
    assert _lattice_distance(camera("bayer-jpeg")(image, seed=0), table) < 0.08
    assert _lattice_distance(camera("phone")(image, seed=0), table) > 0.2


def _high_band_share(image: np.ndarray) -> float:
    """Luma power above 0.3 cycles/px over power at 0.05–0.15 cycles/px."""
    luma = image.astype(np.float64).mean(axis=-1)
    power = np.abs(fft.fft2(luma - luma.mean())) ** 2
    radius = np.hypot(*np.meshgrid(fft.fftfreq(luma.shape[0]), fft.fftfreq(luma.shape[1]), indexing="ij"))
    return float(power[radius > 0.3].sum() / power[(radius > 0.05) & (radius < 0.15)].sum())


def test_the_webcam_loses_the_top_octave_to_its_half_resolution_sensor() -> None:
    image = scenes(4, 128, seed=3)[3]  # dead leaves: power at every scale
    clean, webcam, phone = (_high_band_share(x) for x in (image, camera("webcam")(image, 0), camera("phone")(image, 0)))
    assert webcam < 0.1 * clean and webcam < 0.2 * phone, (clean, webcam, phone)


@pytest.mark.parametrize(("method", "tolerance"), [("bilinear", 0.01), ("bicubic", 0.1)])
def test_misalignment_moves_the_frame_by_its_shift(method: str, tolerance: float) -> None:
    """The centroid of a blob moves by the shift; PIL's bicubic transform moves sub-pixel content a little further
    than asked (0.25 px → 0.34 px, 0.35 → 0.42), its bilinear one exactly: the shift is the resampler's."""
    yy, xx = np.mgrid[0:64, 0:64] + 0.5
    blob = np.exp(-((yy - 32.0) ** 2 + (xx - 30.0) ** 2) / (2 * 3.0**2))[..., None].repeat(3, axis=-1)
    moved = Misalign(0.35, -0.25, 0.0, method)(blob, np.random.default_rng(0), (64, 64))[..., 0]
    centre = [(moved * grid).sum() / moved.sum() for grid in (xx, yy)]
    np.testing.assert_allclose(centre, [30.35, 31.75], atol=tolerance)


def test_cos4_vignetting_darkens_the_corners_by_the_cos4_law() -> None:
    flat = np.ones((200, 200, 3))
    out = Cos4Vignetting(30.0)(flat, np.random.default_rng(0), (200, 200))
    assert out[0, 0, 0] == pytest.approx(np.cos(np.deg2rad(30.0)) ** 4, abs=0.01)
    assert out[100, 100, 0] == pytest.approx(1.0, abs=1e-3)


@pytest.mark.parametrize("base", (*BASES, *CHECK_BASES))
def test_each_scenario_is_its_base_with_one_stage_more(base: str, clean: list[np.ndarray]) -> None:
    rows = SCENARIOS[base]
    assert len(rows) == 11 and rows["control"].stage is None and rows["control"].camera() == camera(base)
    for name, scenario in rows.items():
        if name == "control":
            continue
        changed = scenario.camera()
        assert len(changed.stages) == len(camera(base).stages) + 1 and scenario.stage in changed.stages
        assert scenario.expected and all(label.split()[0] in ("add", "refit") for label in scenario.expected)
        assert changed(clean[0], seed=0).tobytes() != camera(base)(clean[0], seed=0).tobytes(), name
