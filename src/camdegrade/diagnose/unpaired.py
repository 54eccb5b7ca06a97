"""Unpaired mode: clean images and real captures of *other* scenes. Only distribution-level statistics can be
compared (no clean reference per capture), so this gives the "where" part of the report, not the attribution.

Per image: the no-reference families of :mod:`camdegrade.measures.families.no_reference` (a luma radial profile, colour
ratios, tone quantiles, band power, block-edge energy, a flat-pixel noise level). Each component is compared as a
difference of set means over its standard error (both sets), so content differences between the two sets only
count when they exceed what the spread of the images explains. With at least 8 images a side it also reports, as
``fit_statistics``, the statistics :func:`~camdegrade.fitting.unpaired.fit_unpaired` matches (flat-noise ratio,
band log2 power differences, spectrum mismatch: :func:`~camdegrade.fitting.unpaired.unpaired_fidelity`), so a
profile fitted unpaired and diagnosed on the same folders reads the numbers its fit recorded.
"""

from __future__ import annotations

import os
from pathlib import Path

import torch
from torch import Tensor

from camdegrade._support.pixels import as_unit
from camdegrade.diagnose.report import DiagnosisReport
from camdegrade.fitting.unpaired import MIN_IMAGES, unpaired_fidelity
from camdegrade.measures import NO_REFERENCE, image_statistics
from camdegrade.pairs.folder import FolderImages, read_folder
from camdegrade.profile import CameraProfile, as_profile

__all__ = ["diagnose_unpaired"]


def _stack(images: list[Tensor]) -> dict[str, Tensor]:
    per_image = [image_statistics(image) for image in images]
    return {name: torch.stack([p[name] for p in per_image]) for name in NO_REFERENCE}


def _scores(a: dict[str, Tensor], b: dict[str, Tensor]) -> dict[str, float]:
    out = {}
    for name, family in NO_REFERENCE.items():
        x, y = a[name], b[name]
        se2 = (
            torch.nanmean((x - x.nanmean(0)) ** 2, 0) / x.shape[0]
            + torch.nanmean((y - y.nanmean(0)) ** 2, 0) / (y.shape[0])
        )
        z = (x.nanmean(0) - y.nanmean(0)) / (se2 + family.tau**2).sqrt()
        z = z[torch.isfinite(z)]
        out[name] = float(z.pow(2).mean().sqrt()) if z.numel() else 0.0
    return out


def _load(folder: Path, max_images: int | None, skipped: list[dict[str, str]]) -> list[Tensor]:
    """The first ``max_images`` readable images of ``folder`` as unit floats; the others go to ``skipped``."""
    found = read_folder(folder, max_images) if folder.is_dir() else FolderImages()
    if not found.images and not found.skipped:
        raise ValueError(f"{str(folder)!r} must be a folder holding images")
    skipped.extend(found.skipped_records())
    return [as_unit(image) for image in found.images]


def diagnose_unpaired(
    profile: CameraProfile | str | os.PathLike[str],
    clean: str | os.PathLike[str],
    real: str | os.PathLike[str],
    *,
    seed: int = 0,
    max_images: int | None = None,
) -> DiagnosisReport:
    """Compare the profile's simulations of the ``clean`` folder with the captures in ``real`` (other scenes)."""
    base = as_profile(profile)
    skipped: list[dict[str, str]] = []
    cleans, reals = _load(Path(clean), max_images, skipped), _load(Path(real), max_images, skipped)
    if len(cleans) < 4 or len(reals) < 4:
        raise ValueError(f"unpaired mode needs at least 4 clean and 4 real images, got {len(cleans)} and {len(reals)}")
    sims = base.simulate(cleans, seed)
    real_stats, sim_stats = _stack(reals), _stack(sims)
    scores = _scores(real_stats, sim_stats)
    half = len(sims) // 2
    floor_scores = _scores({k: v[:half] for k, v in sim_stats.items()}, {k: v[half:] for k, v in sim_stats.items()})
    gap_value, floor = sum(scores.values()), sum(floor_scores.values())
    where = sorted(
        (
            {
                "axis": name,
                "finding": f"real vs sim set means differ by RMS {scores[name]:.2f} standard errors",
                "score": round(scores[name], 4),
                "null": round(floor_scores[name], 4),
                "significant": scores[name] > max(3 * floor_scores[name], 3.0),
            }
            for name in NO_REFERENCE
        ),
        key=lambda entry: -entry["score"],
    )
    significant = [entry["axis"] for entry in where if entry["significant"]]
    verdict = (
        f"Unpaired: gap {gap_value:.2f} (split-half floor {floor:.2f}); differences in "
        f"{', '.join(significant) or 'nothing beyond the spread of the images'}. Attribution needs paired data."
    )
    report = DiagnosisReport(
        gap_before=gap_value,
        gap_after=gap_value,
        noise_floor=floor,
        where=where,
        effects=[],
        added=[],
        verdict=verdict,
        split=f"unpaired: {len(cleans)} clean images simulated, {len(reals)} real captures",
        held_out_pairs=0,
        families_before=scores,
        families_after=scores,
        profile=None,
        profile_name=base.name,
        mode="unpaired",
    )
    report.skipped = skipped
    if len(cleans) >= MIN_IMAGES and len(reals) >= MIN_IMAGES:  # beside its own: what the unpaired fit matched
        report.fit_statistics = unpaired_fidelity(base, reals, cleans, seed=seed)
        agreement = "agree" if report.fit_statistics["agrees"] else "do not agree"
        report.verdict += f" The unpaired fit's statistics {agreement} (fit_statistics)."
    return report
