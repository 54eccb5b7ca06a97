"""How much of the iPhone X's fine detail a least-squares fit can learn at all: the coherence of each capture with
its clean image, band by band, on the 16 held-out City100 scenes (056–070, 098), whole frames.

For each band of radial frequency (cycles/pixel), over the luma spectra ``C`` (clean) and ``X`` (the capture or a
simulation; Hann window, mean removed), summed over the frames:

- ``log2 X/C``: the power of the image against the clean image's;
- ``log2 |H|²``: the squared gain of the best linear transfer ``H = Σ X·C* / Σ |C|²``, the part of the power a
  least-squares fit can predict from the clean image;
- ``coherence``: ``|Σ X·C*|² / (Σ |X|² · Σ |C|²)``, 1 where the detail lies where the clean image's does, 0 where
  its position is unrelated to it (misregistration, aliasing, the phone's own processing).

Where the capture's coherence is low, its power cannot be predicted from the clean image, so a network fitted by
least squares leaves it out and the simulation is smoother there than the camera (docs/results.md). The last
column is the simulation's power against the capture's. Run from the repo root (about a minute)::

    OMP_NUM_THREADS=2 .venv/bin/python experiments/coherence_city100.py [--profile city100-iphonex]

References:
    J. S. Bendat, A. G. Piersol, "Random Data: Analysis and Measurement Procedures", 4th ed., 2010, ch. 6
    (coherence functions).
"""

from __future__ import annotations

import argparse
import itertools
import math
from pathlib import Path

import torch
from torch import Tensor

from camdegrade import CameraDegrade, load_profile
from camdegrade._support.pixels import as_unit
from camdegrade.fitting import discover_pairs, filter_pairs, load_pair
from camdegrade.functional.analysis.images import hann2d, luma

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real-pairs"
HELD_OUT = {f"{n:03d}" for n in range(56, 71)} | {"098"}
#: Band edges (cycles/pixel): finer than the fidelity bands where the captures' coherence falls.
EDGES = (0.02, 0.05, 0.08, 0.12, 0.16, 0.20, 0.23, 0.25, 0.27, 0.30, 0.35, 0.42, 0.5)


def spectrum(image: Tensor) -> Tensor:
    """The luma spectrum (8-bit levels, Hann window, mean removed) of a ``(3, H, W)`` image in [0, 1]."""
    gray = luma(image[None]).reshape(image.shape[-2:]) * 255.0
    gray = gray - gray.mean()
    return torch.fft.rfft2(gray * hann2d(*gray.shape)).to(torch.complex128)


def band_index(height: int, width: int) -> Tensor:
    """``(H, W // 2 + 1)``: the band of :data:`EDGES` each frequency falls in (``len(EDGES) - 1`` when in none)."""
    radius = torch.sqrt(torch.fft.fftfreq(height)[:, None] ** 2 + torch.fft.rfftfreq(width)[None, :] ** 2)
    index = torch.bucketize(radius, torch.tensor(EDGES), right=True) - 1
    return torch.where((index >= 0) & (index < len(EDGES) - 1), index, len(EDGES) - 1)


class BandSums:
    """Per band: ``Σ X·C*``, ``Σ |X|²`` and ``Σ |C|²`` over the frames added."""

    def __init__(self) -> None:
        bands = len(EDGES)  # the last one collects what lies outside every band
        self.cross_real = torch.zeros(bands, dtype=torch.float64)
        self.cross_imag = torch.zeros(bands, dtype=torch.float64)
        self.image = torch.zeros(bands, dtype=torch.float64)
        self.clean = torch.zeros(bands, dtype=torch.float64)

    def add(self, image: Tensor, clean: Tensor, index: Tensor) -> None:
        flat = index.flatten()
        product = (image * clean.conj()).flatten()
        self.cross_real.index_add_(0, flat, product.real)
        self.cross_imag.index_add_(0, flat, product.imag)
        self.image.index_add_(0, flat, image.abs().pow(2).flatten())
        self.clean.index_add_(0, flat, clean.abs().pow(2).flatten())

    def rows(self) -> list[tuple[float, float, float]]:
        """Per band: ``log2`` power against the clean image's, ``log2 |H|²`` and the coherence."""
        out = []
        for band in range(len(EDGES) - 1):
            cross = float(self.cross_real[band] ** 2 + self.cross_imag[band] ** 2)
            image, clean = float(self.image[band]), float(self.clean[band])
            out.append((math.log2(image / clean), math.log2(cross / clean**2), cross / (image * clean)))
        return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--profile", default="city100-iphonex", help="built-in name or .safetensors path")
    args = parser.parse_args()
    profile = load_profile(args.profile)
    pairs = filter_pairs(discover_pairs(args.data / "pairs.csv").pairs, subset="city100_iPhoneX")
    held = [pair for pair in pairs if pair.scene in HELD_OUT]
    capture, simulation = BandSums(), BandSums()
    for index, pair in enumerate(held):
        clean, real = load_pair(pair)
        sampled = as_unit(CameraDegrade(profile, seed=index)(clean))
        spectra = spectrum(as_unit(clean)), spectrum(as_unit(real)), spectrum(sampled)
        bands = band_index(*clean.shape[-2:])
        capture.add(spectra[1], spectra[0], bands)
        simulation.add(spectra[2], spectra[0], bands)
    print(f"{len(held)} held-out City100 frames; simulation: {args.profile}")
    print("| cycles/px | capture: log2 X/C | log2 \\|H\\|² | coherence | simulation: log2 X/C | log2 \\|H\\|² "
          "| coherence | log2 sim/capture |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for (low, high), real, sim in zip(itertools.pairwise(EDGES), capture.rows(), simulation.rows(), strict=True):
        print(
            f"| {low:.2f}–{high:.2f} | {real[0]:+.2f} | {real[1]:+.2f} | {real[2]:.3f} | {sim[0]:+.2f} | {sim[1]:+.2f} "
            f"| {sim[2]:.3f} | {sim[0] - real[0]:+.2f} |"
        )


if __name__ == "__main__":
    main()
