"""The statistics' accepted changes judged by an image-only critic (:mod:`camdegrade.diagnose.critic_check`): a change
that makes the simulation easier to tell from the camera from the image alone is held back, with every change
accepted after it; one that makes it harder is let through."""

from __future__ import annotations

import dataclasses
import json

import pytest
import torch

import camdegrade.diagnose.core as core
from camdegrade.diagnose import diagnose
from camdegrade.diagnose.attribution.attribute import attribute, keeping
from camdegrade.diagnose.attribution.changes import Change, add_effect
from camdegrade.diagnose.critic_check import CriticCheck, check_changes, closes_most, uncovered_clause
from camdegrade.diagnose.critique import Critique
from camdegrade.diagnose.verdict import held_back_clause
from camdegrade.effects import Blur, Noise
from camdegrade.measures.critic import CriticResult
from camdegrade.measures.visible import TextureComparison
from camdegrade.profile import CameraProfile
from camdegrade.sim import VirtualCamera
from test_diagnose_critic import camera_pairs, diagnose_adding, named

torch.set_num_threads(1)

pytestmark = pytest.mark.slow  # each test trains two or three image-only critics: 10–25 s on one core

NOISE = Noise(a=0.0005)


def _with_change(camera: VirtualCamera, profile: CameraProfile, change_effect: Blur):
    """The pairs of ``camera`` (6 calibration, 6 held-out), ``profile`` attributed on them with nothing tried, and
    that result with one change accepted by hand: ``change_effect`` added, said to close a tenth of a gap of 10 (one
    that closes most of the gap is never held back)."""
    calibration = named("cal-", camera_pairs(camera, 6, 64, seed=0))
    held = named("held-", camera_pairs(camera, 6, 64, seed=1))
    result = attribute(profile, calibration.unit_pairs(), held.unit_pairs(), candidates=[], kinds=("add",))
    changed = add_effect(profile, change_effect)
    change = Change("add", change_effect.name, changed, change_effect, gap_after=9.0, reduction=1.0, significant=True)
    return dataclasses.replace(result, accepted=[change]), held


def test_a_change_that_blurs_a_matching_profile_is_held_back() -> None:
    """The profile is the camera: the critic cannot tell them apart; a blur of σ 2 px it tells from the image alone
    at once, so the check holds it back, and ``keeping`` returns the profile as given."""
    camera = VirtualCamera([NOISE], scale=1.0)
    profile = CameraProfile(None, [NOISE], name="matching")
    result, held = _with_change(camera, profile, Blur(sigma_x=2.0))
    check = check_changes(result, held, held.unit_pairs(), 0, lambda message: None)
    assert check.kept == 0 and check.held_back is not None and check.later == []
    before, after = check.steps[0][1].result, check.held_back[1].result
    assert before.accuracy < 0.7 and after.accuracy > max(before.high, 0.8), (before, after)
    kept = keeping(result, check.kept, profile)
    assert kept.accepted == [] and kept.final_profile is profile and kept.final_sims is result.baseline.sims
    data = check.to_dict()
    assert data["held_back"]["change"] == "add blur" and data["steps"][0]["change"] == "the profile as given"


def test_a_change_that_brings_the_camera_s_blur_is_let_through() -> None:
    """The camera blurs (σ 1.5 px), the profile does not: adding that blur makes the critic less sure, and the
    check lets it through with its critic as the last step."""
    camera = VirtualCamera([Blur(sigma_x=1.5), NOISE], scale=1.0)
    profile = CameraProfile(None, [NOISE], name="sharp")
    result, held = _with_change(camera, profile, Blur(sigma_x=1.5))
    check = check_changes(result, held, held.unit_pairs(), 0, lambda message: None)
    assert check.held_back is None and check.kept == 1
    before, after = check.steps[0][1].result, check.steps[1][1].result
    assert before.accuracy > 0.8 and after.accuracy < before.accuracy - 0.2, (before, after)


def test_the_diagnosis_reports_a_held_back_change_and_returns_the_profile_without_it(monkeypatch, tmp_path) -> None:
    """Through :func:`diagnose`: the statistics accept adding the camera's slight blur (σ 0.4 px, which the image-only
    critic barely sees: 0.59 [0.51–0.68]); the change is replaced, before the check, by one that also draws 40× the
    noise (what the statistics might accept and a model sees at once: 0.92) and is said to close a fifth of the gap
    (one that closes most of it is kept). The diagnosis holds it back: nothing accepted, the profile as given, and
    the verdict and the JSON say why."""
    camera = VirtualCamera([Blur(sigma_x=0.4), NOISE], scale=1.0)
    profile = CameraProfile(None, [NOISE], name="sharp")
    real_check = core.check_changes

    def overdone(result, *args):
        (first, *rest) = result.accepted
        worse = CameraProfile(None, [Blur(sigma_x=0.4), Noise(a=0.02)], name="grainy")
        fifth = first.reduction / 5
        result.accepted[:] = [
            dataclasses.replace(first, profile=worse, reduction=fifth, gap_after=first.gap_after + 4 * fifth),
            *rest,
        ]
        return real_check(result, *args)

    monkeypatch.setattr(core, "check_changes", overdone)
    report = diagnose_adding(profile, camera, "blur")
    assert report.accepted == [] and report.added == []
    assert [stage.name for stage in report.profile.effects] == ["noise"]
    assert report.verdict.startswith("No change is accepted") and "Held back: adding blur" in report.verdict
    data = json.loads(report.write_json(tmp_path / "report.json").read_text())
    assert data["critic_check"]["held_back"]["change"] == "add blur"
    assert data["critic"]["after (image only)"] == data["critic"]["before (image only)"]
    page = report.to_html()
    assert "checked by the image-only critic" in page and "held back: texture too sharp" in page, page[:2000]


def test_a_change_that_closes_most_of_the_gap_is_kept_and_what_it_uncovers_is_reported() -> None:
    """The same blur of σ 2 px on a matching profile, said to close the whole gap: the critic is as sure with it as
    when it is held back, but a change that closes most of the gap is kept, and the check reports it as uncovering
    what is left."""
    camera = VirtualCamera([NOISE], scale=1.0)
    profile = CameraProfile(None, [NOISE], name="matching")
    result, held = _with_change(camera, profile, Blur(sigma_x=2.0))
    result.accepted[0].gap_after, result.accepted[0].reduction = 0.0, 10.0
    check = check_changes(result, held, held.unit_pairs(), 0, lambda message: None)
    assert check.held_back is None and check.kept == 1
    ((change, before, after, texture),) = check.uncovered
    assert change is result.accepted[0] and after.result.accuracy > max(before.result.high, 0.8)
    assert check.to_dict()["uncovered"][0]["change"] == "add blur"
    clause = uncovered_clause(check)
    assert clause.startswith(" Uncovered: with add blur, which closes most of the gap, a critic") and (
        texture.describe() in clause
    ), clause


def test_max_added_below_one_is_refused_by_name() -> None:
    with pytest.raises(ValueError, match="max_added must be an integer of at least 1, got max_added=0"):
        diagnose(CameraProfile(None, []), [], max_added=0)


def test_the_verdict_names_the_change_held_back_and_the_ones_accepted_on_top_of_it() -> None:
    """Partial: the first change let through, the second held back with the third, accepted on top of it."""

    def critique(accuracy: float, low: float, high: float) -> Critique:
        return Critique(CriticResult(accuracy, low, high, 384, 8, 1.0), None, [])  # type: ignore[arg-type]

    first = Change("add", "tone", None, None, 1.0, reduction=2.0, significant=True)
    refit = Change("refit", "denoise", None, None, 1.0, reduction=1.3, significant=True, before=[first])
    refit.description = "denoise stage is 10.0× too weak"
    jpeg = Change("add", "jpeg", None, None, 1.0, reduction=1.1, significant=True, before=[first, refit])
    smooth = TextureComparison([-0.9, -1.2], [0.05, 0.05], [True, True], 8)
    within = TextureComparison([-0.1, -0.2], [0.05, 0.05], [False, False], 8)
    check = CriticCheck(
        [("the profile as given", critique(0.70, 0.66, 0.74)), ("add tone", critique(0.62, 0.58, 0.66))],
        (refit, critique(0.79, 0.74, 0.85)),
        later=[jpeg],
        texture=(within, smooth),
    )
    clause = held_back_clause(check, "phone")
    assert clause.startswith(" Held back: refitting denoise closes the statistics' gap (−1.30)"), clause
    assert "(0.62 [0.58–0.66] → 0.79 [0.74–0.85])" in clause and smooth.describe() in clause
    assert clause.endswith(" Held back with it, as accepted on top of it: add jpeg."), clause
    data = json.loads(json.dumps(check.to_dict(), allow_nan=False))
    assert [step["change"] for step in data["steps"]] == ["the profile as given", "add tone"] and check.kept == 1
    assert data["held_back"]["change"] == "refit denoise" and data["later_held_back"] == ["add jpeg"]


def test_closing_most_of_the_gap_is_more_than_half_of_it_above_the_profile_against_itself() -> None:
    """An exposure fixed by a tone curve: 66.5 of a gap of 90.5 (null 2) is most of it; 1.3 of 12.8 is not."""
    tone = Change("add", "tone", None, None, 24.0, reduction=66.5, significant=True)
    denoise = Change("refit", "denoise", None, None, 11.47, reduction=1.3, significant=True)
    assert closes_most(tone, 2.0) and not closes_most(denoise, 0.0)
    assert not closes_most(Change("add", "tone", None, None, 6.0, reduction=3.0), 1.0)  # 3 of the 8 above the null
