"""A change names its cause by the statistic only that cause leaves (issue 42, item 3): a change to the resampler by
the resampling trace (:mod:`camdegrade.diagnose.attribution.resampler`), a misalignment by where things are, whatever
the simulator's interpolation does to the texture (:mod:`camdegrade.diagnose.attribution.signature`)."""

from __future__ import annotations

from types import SimpleNamespace

import torch

from camdegrade.diagnose.attribution.changes import Change
from camdegrade.diagnose.attribution.resampler import resampler_unsupported
from camdegrade.diagnose.attribution.signature import agreement, judge_cause
from camdegrade.diagnose.core import _missing_rows
from camdegrade.diagnose.heldout import Baseline, HeldOut
from camdegrade.effects import Blur, Misalignment, Resolution
from camdegrade.measures import FAMILIES, family_gaps
from camdegrade.profile import CameraProfile
from test_diagnose_critic import scenes

torch.set_num_threads(1)


def _round(camera: CameraProfile, profile: CameraProfile, count: int = 8) -> tuple[SimpleNamespace, HeldOut]:
    """``profile`` measured against ``camera``'s captures on ``count`` held-out pairs of 64²: a round's view."""
    cleans = scenes(count, 64, seed=3)
    reals = camera.simulate(cleans, 0, stream="camera")
    held = HeldOut.build(list(zip(cleans, reals)), 0, "held-out")
    baseline = Baseline.measure(held, profile)
    search = SimpleNamespace(held=held, baseline=baseline)
    return SimpleNamespace(search=search, stats=baseline.stats, current=profile), held


def _change(kind: str, name: str, round_: SimpleNamespace, held: HeldOut, profile: CameraProfile) -> Change:
    """``profile`` as the change ``kind name`` on top of the round's profile, significant on its whole gap."""
    stats, _ = held.statistics(profile)
    after = held.gap(stats)
    families = family_gaps(held.real, stats, scale=held.scale)
    reduction = round_.search.baseline.gap - after
    change = Change(kind, name, profile, None, after, reduction, 0.1, True, families, stats=stats)
    change.reduction_needed = 0.5
    return change


def test_a_resampler_refit_that_only_smooths_is_not_a_cause_and_the_blur_is() -> None:
    """The camera blurs (σ 1.5 px) before its 2× upscale; the profile has the upscale. The camera's own chain, named
    as a refit of the resampler, closes the gap as much as adding the blur, and its own statistic (the transfer)
    agrees; but the simulation shows the captures' upscale period already: the resampling does not differ, and the
    blur is named."""
    camera = CameraProfile(None, [Blur(sigma_x=1.5), Resolution(0.5)])
    round_, held = _round(camera, CameraProfile(None, [Resolution(0.5)]))
    refit = _change("refit", "resolution", round_, held, camera)
    blur = _change("add", "blur", round_, held, camera)
    assert refit.reduction > 1.0 and agreement(refit, round_).agrees
    judge_cause(refit, round_)
    judge_cause(blur, round_)
    assert refit.not_a_cause and not refit.significant
    assert "the resampling trace finds period 2 in the captures and 2 in the simulation before" in refit.description
    assert blur.significant and not blur.not_a_cause


def test_a_resampler_refit_to_the_captures_period_is_a_cause() -> None:
    """The camera's sensor has a quarter of the pixels per axis (period 4), the profile's half (period 2): a refit to
    a quarter makes the simulation's trace the captures', and is a cause."""
    camera = CameraProfile(None, [Resolution(0.25)])
    round_, held = _round(camera, CameraProfile(None, [Resolution(0.5)]))
    refit = _change("refit", "resolution", round_, held, camera)
    assert resampler_unsupported(refit, round_) == ""
    judge_cause(refit, round_)
    assert refit.significant and not refit.not_a_cause, refit.description


def _shifted_round() -> tuple[SimpleNamespace, HeldOut]:
    """A camera shifted by (0.6, −0.5) px, a profile without the shift."""
    camera = CameraProfile(None, [Misalignment(dx=0.6, dy=-0.5)])
    return _round(camera, CameraProfile(None, []))


def test_a_misalignment_whose_interpolation_smooths_the_texture_is_named_by_where_things_are() -> None:
    """The shift fixed by an interpolation much smoother than the camera's (the shift, then a blur of σ 1.5 px): the
    texture goes too smooth, which alone would say "not a cause"; the displacement, which no texture fakes, moves
    to the camera's, so the misalignment is named, and the texture is said."""
    round_, held = _shifted_round()
    smoothed = CameraProfile(None, [Misalignment(dx=0.6, dy=-0.5), Blur(sigma_x=1.5)])
    change = _change("add", "misalignment", round_, held, smoothed)
    verdict = agreement(change, round_)
    assert verdict.texture is not None and verdict.geometry is not None
    assert verdict.geometry.families == ("alignment",) and verdict.geometry.agrees and verdict.agrees
    judge_cause(change, round_)
    assert change.significant and not change.not_a_cause
    assert change.description.startswith("named by where things are (alignment); texture too smooth"), (
        change.description
    )


def test_a_change_that_smooths_the_texture_without_moving_where_things_are_is_still_not_a_cause() -> None:
    """A "misalignment" that only blurs (σ 1.5 px, no shift) moves the texture away and the displacement not at
    all: not a cause. A blur has no geometric statistic to be named by."""
    round_, held = _shifted_round()
    change = _change("add", "misalignment", round_, held, CameraProfile(None, [Blur(sigma_x=1.5)]))
    judge_cause(change, round_)
    assert change.not_a_cause and "but the texture away from the camera's" in change.description
    assert [name for name, family in FAMILIES.items() if family.geometric] == ["alignment"]


def test_an_effect_tried_at_two_places_is_marked_accepted_at_the_one_accepted() -> None:
    """Noise tried before and after a resampler (two changes "add noise"), the one after accepted: the missing
    ranking marks that one accepted and not the other (a report listed "add noise" accepted twice). An effect at one
    place, accepted on top of another change (another object), stays marked."""
    after = Change("add", "noise", None, None, 5.0, 6.0, 0.5, True, description="adds noise after resolution")
    before = Change("add", "noise", None, None, 9.0, 2.0, 0.5, True)
    blur, blur_on_top = (Change("add", "blur", None, None, gap, 1.0, 0.2, True) for gap in (10.0, 4.0))
    result = SimpleNamespace(missing=[after, blur_on_top], missing_ranking=[after, before, blur])
    rows = _missing_rows(result)
    assert [(row["name"], row["accepted"]) for row in rows] == [("noise", True), ("noise", False), ("blur", True)]
