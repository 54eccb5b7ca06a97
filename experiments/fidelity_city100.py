"""How far the built-in City100 profiles are from the iPhone X's own captures (issue 23's baseline).

For the 16 held-out City100 scenes (056–070, 098; never used in any fit), whole frames, each row below is a
simulation of the clean images measured against the real captures with :mod:`camdegrade.measures.fidelity`:

- grid: the RMS of the 4×4-periodic pattern of ``Y − box9(Y)``, simulation over capture;
- five bands: the mean over frames of ``log2(power sim / power real)`` of the luma spectrum (cycles/pixel);
- noise, banding: the flat-pixel noise std and the row-mean std, simulation over capture;
- PSNR: mean paired PSNR of simulation against capture;
- critic: the held-out accuracy of the learned critic (:mod:`camdegrade.measures.critic`) with the clean source
  (paired) and from the image alone (what a model trained on the simulation sees): ``--critic-seeds`` seeds, each
  training one critic on 8 of the scenes and scoring it on the other 8 and back (0.5: cannot tell); the mean ± the
  critics' std, and the 95 % interval over scenes.

Rows: the clean source itself, ``city100-iphonex`` and ``city100-iphonex-fast`` sampled as training sees them
(``CameraDegrade``, seed = scene index), the built-in's network alone, and the built-in followed by an unsharp
mask (σ 1, amount 0.5), and the simple answer issue 23 compares with: a blur and a 12-number affine colour map,
both least squares on scenes 001–055 (``experiments/critic_evidence.py``). It prints a markdown table and writes
``docs/fidelity_city100.png``: real and simulated crops side by side (flat at 1:1, textured at 2×
nearest-neighbour) and the radial power spectra. Run from the repo root::

    OMP_NUM_THREADS=2 .venv/bin/python experiments/fidelity_city100.py [--data DIR] [--png PATH] [--json PATH]
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import torch
from critic_evidence import TRAINING, blurred_and_mapped, city100_pairs, fit_blur_and_colour_map
from fidelity_report import band_cell, band_heading, best_window, labelled_grid, number, real_pairs_parser, save_png
from PIL import Image
from torch import Tensor

from camdegrade import CameraDegrade, load_profile
from camdegrade._support.pixels import as_unit, unit_to_bytes
from camdegrade.fitting import discover_pairs, filter_pairs, load_pair
from camdegrade.functional.analysis.images import flat_mask, gradient_energy, hann2d, luma
from camdegrade.functional.optics.blur import blur_image
from camdegrade.measures.critic import repeated_critic_test
from camdegrade.measures.fidelity import BAND_EDGES, measure_fidelity

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DATA = ROOT.parent / "shared" / "data" / "real-pairs"
HELD_OUT = sorted({f"{n:03d}" for n in range(56, 71)} | {"098"})
SHOWN = ("060", "062", "098")
ROWS = [
    "clean source",
    "city100-iphonex",
    "city100-iphonex-fast",
    "network alone",
    "built-in + unsharp",
    "blur + colour map",
]
SHOWN_ROWS = ["real", "city100-iphonex", "city100-iphonex-fast", "network alone", "built-in + unsharp"]
#: Extra rows: ``--profile LABEL=PATH`` profiles (a refit to compare with the built-ins), sampled like them.
EXTRA: dict[str, CameraDegrade] = {}
UNSHARP_SIGMA, UNSHARP_AMOUNT = 1.0, 0.5
CROP, ZOOMED = 128, 64


def held_out_pairs(data: Path) -> list[tuple[str, Tensor, Tensor]]:
    """``(scene, clean, real)`` uint8 for the held-out City100 iPhone X scenes."""
    pairs = {p.scene: p for p in filter_pairs(discover_pairs(data / "pairs.csv").pairs, subset="city100_iPhoneX")}
    return [(scene, *load_pair(pairs[scene])) for scene in HELD_OUT]


def unsharp(image: Tensor) -> Tensor:
    """``image + amount · (image − blur_σ(image))`` on uint8, back to uint8."""
    unit = as_unit(image)
    return unit_to_bytes((unit + UNSHARP_AMOUNT * (unit - blur_image(unit, UNSHARP_SIGMA))).clamp(0, 1))


def simulations(index: int, clean: Tensor) -> dict[str, Tensor]:
    """Every row's uint8 image of ``clean`` (the profiles sampled with seed ``index``, as training sees them)."""
    built_in, fast = load_profile("city100-iphonex"), load_profile("city100-iphonex-fast")
    sampled = CameraDegrade(built_in, seed=index)(clean)
    return {
        "clean source": clean,
        "city100-iphonex": sampled,
        "city100-iphonex-fast": CameraDegrade(fast, seed=index)(clean),
        "network alone": CameraDegrade(built_in.with_chain([]), seed=index)(clean),
        "built-in + unsharp": unsharp(sampled),
        **{
            label: degrade.profile and CameraDegrade(degrade.profile, seed=index)(clean)
            for label, degrade in EXTRA.items()
        },
    }


def radial_power(image: Tensor, bins: int = 64) -> Tensor:
    """``(bins,)`` mean luma power (Hann window) per radial frequency bin over [0, 0.5] cycles/pixel."""
    gray = luma(as_unit(image)) * 255.0
    height, width = gray.shape
    power = torch.fft.rfft2((gray - gray.mean()) * hann2d(height, width)).abs().pow(2).double() / (height * width)
    radius = torch.sqrt(torch.fft.fftfreq(height)[:, None] ** 2 + torch.fft.rfftfreq(width)[None, :] ** 2)
    index = (radius / 0.5 * bins).long()
    inside = index < bins
    sums = torch.bincount(index[inside], weights=power[inside], minlength=bins)
    return sums / torch.bincount(index[inside], minlength=bins).clamp_min(1)


def measure(data: Path, critic_seeds: int = 4) -> tuple[list[dict], dict, dict]:
    """The table's rows, the crops shown, and the mean radial spectra per row."""
    frames: dict[str, list[Tensor]] = {name: [] for name in ("clean", "real", *ROWS)}
    shown: dict[str, dict[str, Tensor]] = {}
    for index, (scene, clean, real) in enumerate(held_out_pairs(data)):
        images = {"clean": clean, "real": real, **simulations(index, clean)}
        for name, image in images.items():
            frames[name].append(image)
        if scene in SHOWN:
            shown[scene] = images
    blur, colour_map = fit_blur_and_colour_map(city100_pairs(data, TRAINING))
    frames["blur + colour map"] = [
        unit_to_bytes(blurred_and_mapped(clean, blur, colour_map)) for clean in frames["clean"]
    ]
    spectra = {name: torch.stack([radial_power(i) for i in frames[name]]).mean(0) for name in ("real", *ROWS)}
    cleans = [as_unit(image) for image in frames["clean"]]
    reals = [as_unit(image) for image in frames["real"]]
    rows = []
    for name in ROWS:
        sims = [as_unit(image) for image in frames[name]]
        report = measure_fidelity(sims, reals, cleans)
        critics = {
            mode: repeated_critic_test((cleans, reals, sims), HELD_OUT, critic_seeds, image_only=only).to_dict()
            for mode, only in (("paired", False), ("image_only", True))
        }
        rows.append({"row": name, **report.to_dict(), "critic": critics})
    return rows, shown, spectra


def format_table(rows: list[dict]) -> str:
    lines = [
        f"| image | grid ratio | {band_heading()} | noise ratio | banding ratio | PSNR dB "
        "| critic paired | critic image-only |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        paired, only = row["critic"]["paired"], row["critic"]["image_only"]
        lines.append(
            f"| {row['row']} | {number(row['grid_ratio'], 1)} ({row['grid_sim']:.3f} / {row['grid_real']:.3f}) "
            f"| {band_cell(row['bands'])} | {number(row['noise_ratio'])} | {number(row['banding_ratio'])} "
            f"| {row['psnr']:.2f} "
            f"| {_critic(paired)} | {_critic(only)} |"
        )
    return "\n".join(lines)


def _critic(result: dict) -> str:
    return f"{result['accuracy']:.3f} ± {result['std']:.2f} [{result['low']:.2f}–{result['high']:.2f}]"


def _tiles(shown: dict[str, dict[str, Tensor]]) -> list[tuple[str, list[Image.Image]]]:
    """Per scene: the flattest ``CROP``² window at 1:1 and the most textured ``ZOOMED``² window at 2×."""
    tiles = []
    for scene, images in shown.items():
        unit_clean = as_unit(images["clean"])
        flat = best_window(flat_mask(unit_clean), CROP)
        textured = best_window(gradient_energy(unit_clean), ZOOMED)
        for kind, (top, left), side in (("flat 1:1", flat, CROP), ("texture 2x", textured, ZOOMED)):
            crops = [images[name][:, top : top + side, left : left + side] for name in SHOWN_ROWS]
            pictures = [Image.fromarray(crop.permute(1, 2, 0).numpy()) for crop in crops]
            pictures = [p.resize((CROP, CROP), Image.NEAREST) for p in pictures]
            tiles.append((f"{scene} {kind}", pictures))
    return tiles


def spectrum_plot(spectra: dict[str, Tensor]) -> Image.Image:
    """Mean radial luma power per row against the real captures' (log scale), as an image."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, 2, figsize=(9, 3.4), dpi=100)
    frequency = (torch.arange(len(spectra["real"])) + 0.5) / len(spectra["real"]) * 0.5
    for name, power in spectra.items():
        axes[0].semilogy(frequency, power, label=name, lw=2.0 if name == "real" else 1.2)
        axes[1].plot(frequency, torch.log2(power / spectra["real"]), label=name)
    axes[0].set(xlabel="cycles/pixel", ylabel="luma power (levels²)", title="radial power, 16 held-out frames")
    axes[1].set(xlabel="cycles/pixel", ylabel="log2(sim / real)", title="power relative to the capture")
    axes[1].axhline(0, color="black", lw=0.6)
    for edge in BAND_EDGES:
        axes[1].axvline(edge, color="grey", lw=0.4, ls=":")
    axes[0].legend(fontsize=7)
    figure.tight_layout()
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png")
    plt.close(figure)
    buffer.seek(0)
    return Image.open(buffer).convert("RGB")


def evidence_png(shown: dict[str, dict[str, Tensor]], spectra: dict[str, Tensor], path: Path) -> None:
    """Crops (rows: scene and kind; columns: real, then each simulation) above the spectrum plot."""
    grid = labelled_grid(SHOWN_ROWS, _tiles(shown), CROP, label_drop=6)
    plot = spectrum_plot(spectra)
    canvas = Image.new("RGB", (max(grid.width, plot.width), grid.height + plot.height), "white")
    canvas.paste(grid, (0, 0))
    canvas.paste(plot, (0, grid.height))
    save_png(canvas, path)


def main(argv: list[str] | None = None) -> int:
    parser = real_pairs_parser(__doc__, DEFAULT_DATA)
    parser.add_argument("--png", type=Path, default=ROOT / "docs" / "fidelity_city100.png")
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "results" / "fidelity_city100.json")
    parser.add_argument("--profile", action="append", default=[], metavar="LABEL=PATH", help="an extra row")
    parser.add_argument("--critic-seeds", type=int, default=4, help="critic seeds (two critics each)")
    args = parser.parse_args(argv)
    for item in args.profile:
        label, _, path = item.partition("=")
        EXTRA[label] = CameraDegrade(load_profile(path), seed=0)
        ROWS.append(label)
        SHOWN_ROWS.append(label)
    if not (args.data / "pairs.csv").is_file():
        parser.error(f"no pairs.csv in {args.data}; pass --data with the real-pairs folder")
    rows, shown, spectra = measure(args.data, args.critic_seeds)
    print(format_table(rows))
    evidence_png(shown, spectra, args.png)
    print(f"wrote {args.png}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(rows, indent=2, allow_nan=False) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
