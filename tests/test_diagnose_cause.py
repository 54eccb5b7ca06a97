"""Which change the diagnosis names as the cause (issue 42, item 3): a candidate at every place in the chain where it
would look different (:mod:`camdegrade.diagnose.attribution.placement`), and a change accepted only where its own
statistics agree (:mod:`camdegrade.diagnose.attribution.signature`)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch

from camdegrade import load_profile
from camdegrade.diagnose import diagnose
from camdegrade.diagnose.attribution.changes import KINDS, Change
from camdegrade.diagnose.attribution.placement import Placement, placements
from camdegrade.diagnose.attribution.search import prefer_simpler
from camdegrade.diagnose.attribution.signature import (
    Agreement,
    _texture,
    agreement,
    judge_cause,
    not_a_cause_clause,
    own_families,
)
from camdegrade.diagnose.heldout import Baseline, HeldOut
from camdegrade.effects import EFFECTS, Blur, Color, Noise, Resolution, Sharpen, Vignetting
from camdegrade.measures import family_gaps
from camdegrade.profile import CameraProfile
from test_diagnose_critic import named, scenes

torch.set_num_threads(1)


def _webcam() -> CameraProfile:
    """A profile shaped like a webcam's fit: optics, the sensor's noise, an upscale, sharpening."""
    return CameraProfile(None, [Vignetting(k1=-0.2), Noise(a=0.0004), Resolution(0.5), Sharpen(1.0, 0.5)])


def test_noise_is_tried_after_each_stage_that_mixes_pixels_and_a_tone_curve_nowhere_else() -> None:
    """Noise's signature (its correlation with the next pixel) changes through a resampler or a filter, so it is tried
    after the upscale and after the sharpening, beside the sensor noise it is at; a codec's blocks, before each of
    them. A tone curve looks the same anywhere: no other place."""
    profile = _webcam()
    assert placements(profile, "noise") == [
        Placement("noise", 3, after="resolution"),
        Placement("noise", 4, after="sharpen"),
    ]
    assert placements(profile, "jpeg") == [
        Placement("jpeg", 2, before="resolution"),
        Placement("jpeg", 3, before="sharpen"),
    ]
    assert placements(profile, "tone") == placements(profile, "vignetting") == []
    assert placements(CameraProfile(None, [Noise(a=0.0004)]), "noise") == []  # nothing mixes pixels after it
    assert placements(CameraProfile(None, [Blur(sigma_x=1.0), Noise(a=0.0004)]), "jpeg") == []  # not before the lens


def test_a_place_stays_when_a_change_removes_the_stage_it_followed() -> None:
    """A phone's profile: the sensor's noise, then a sharpening. Noise after the sharpening is tried; once a change
    removes the sharpening (the camera lacks it), that place is still tried, at the end of the chain, beside the
    sensor's noise; a codec's place before the sharpening is then its own, not tried twice."""
    diagnosed = CameraProfile(None, [Noise(a=0.0004), Sharpen(1.0, 0.5)])
    assert placements(diagnosed, "noise") == [Placement("noise", 2, after="sharpen")]
    current = CameraProfile(None, [Noise(a=0.0004)])
    assert placements(current, "noise") == []
    (moved,) = placements(current, "noise", diagnosed)
    assert moved == Placement("noise", 1, after="noise", was_after="sharpen")
    assert moved.where == "after noise, where sharpen was"
    assert placements(current, "jpeg", diagnosed) == []
    assert placements(_webcam(), "noise", _webcam()) == placements(_webcam(), "noise")


def test_a_placed_candidate_is_added_beside_the_stages_it_follows_and_the_profile_saves_and_loads(tmp_path) -> None:
    """The second noise source after the upscale keeps the sensor's; the add plans carry it although the profile
    has a noise stage already; the profile with it saves and loads back in that order."""
    profile = _webcam()
    second = Noise(a=0.002)
    placed = Placement("noise", 3, after="resolution").insert(profile, second)
    assert [stage.name for stage in placed.effects] == ["vignetting", "noise", "resolution", "noise", "sharpen"]
    assert [stage.name for stage in profile.effects] == ["vignetting", "noise", "resolution", "sharpen"]
    plans = KINDS["add"].plans(profile, ["noise", "tone"], set())
    assert [(plan.name, plan.target) for plan in plans] == [
        ("tone", "tone"),
        ("noise", Placement("noise", 3, after="resolution")),
        ("noise", Placement("noise", 4, after="sharpen")),
    ]
    placed.save(tmp_path / "placed.safetensors")
    loaded = load_profile(tmp_path / "placed.safetensors")
    assert [stage.name for stage in loaded.effects] == ["vignetting", "noise", "resolution", "noise", "sharpen"]
    assert torch.equal(loaded.effects[3].state_dict()["a"], second.state_dict()["a"])


def _cast_round() -> tuple[SimpleNamespace, HeldOut]:
    """A camera with a warm colour cast, a profile without it (nothing), measured on 8 held-out pairs of 64²."""
    cast = CameraProfile(None, [Color(torch.diag(torch.tensor([1.2, 1.0, 0.8])))])
    cleans = scenes(8, 64, seed=3)
    reals = cast.simulate(cleans, 0, stream="camera")
    held = HeldOut.build(list(zip(cleans, reals)), 0, "held-out")
    baseline = Baseline.measure(held, CameraProfile(None, []))
    search = SimpleNamespace(held=held, baseline=baseline)
    return SimpleNamespace(search=search, stats=baseline.stats, current=CameraProfile(None, [])), held


def _change(kind: str, name: str, held: HeldOut, gap_now: float, profile: CameraProfile) -> Change:
    stats, _ = held.statistics(profile)
    after = held.gap(stats)
    families = family_gaps(held.real, stats, scale=held.scale)
    change = Change(kind, name, profile, None, after, gap_now - after, 0.1, True, families, stats=stats)
    change.reduction_needed = 0.5
    return change


@pytest.mark.slow  # the held-out statistics and their bootstrap: about 4 s on one core
def test_a_refit_that_lowers_the_gap_through_statistics_it_does_not_explain_is_not_a_cause() -> None:
    """The colour cast fixed under the name of a sharpening refit (its own statistic, the transfer function, was
    right already) lowers the gap as much as adding the colour matrix; only the colour matrix, whose statistics
    (spatial, intensity, colour) differ and move to the camera's, stays significant."""
    round_, held = _cast_round()
    gap_now = round_.search.baseline.gap
    fixed = CameraProfile(None, [Color(torch.diag(torch.tensor([1.2, 1.0, 0.8])))])
    refit = _change("refit", "sharpen", held, gap_now, fixed)
    add = _change("add", "color", held, gap_now, fixed)
    assert refit.reduction == add.reduction and refit.reduction > 0.5 * gap_now
    judge_cause(refit, round_)
    judge_cause(add, round_)
    assert not refit.significant and refit.not_a_cause
    assert "not a cause: its own statistics (frequency) match the camera already" in refit.description
    assert add.significant and not add.not_a_cause and add.description == ""
    clause = not_a_cause_clause([add, refit])
    assert clause.startswith(" Lowering the gap without naming its cause: refit sharpen (gap −"), clause
    assert clause.count("not a cause") == 1 and not_a_cause_clause([add]) == ""
    assert own_families("network", "network") == ("frequency", "blocks")


@pytest.mark.slow  # the held-out statistics and their bootstrap: about 4 s on one core
def test_a_change_that_takes_the_texture_away_from_the_camera_s_is_not_a_cause() -> None:
    """A blur of σ 2 px and the colour cast together lower the gap (the cast is most of it), and the blur's own
    statistic, the transfer function, moves; but the texture goes from the camera's to far too smooth, which no
    camera detail explains: not a cause, said with the texture."""
    round_, held = _cast_round()
    both = CameraProfile(None, [Blur(sigma_x=2.0), Color(torch.diag(torch.tensor([1.2, 1.0, 0.8])))])
    blur = _change("add", "blur", held, round_.search.baseline.gap, both)
    verdict = agreement(blur, round_)
    assert verdict.texture is not None and not verdict.agrees
    before, after = verdict.texture
    assert before.worst == 0.0 and after.worst > 1.0 and after.direction == "smooth", (before, after)
    judge_cause(blur, round_)
    assert blur.not_a_cause and "but the texture away from the camera's: texture too smooth" in blur.description


def test_a_change_whose_own_statistics_move_less_than_a_reduction_must_is_not_a_cause() -> None:
    """The network fine-tune that closes a colour cast (16.5 off the gap) moves its own statistics by 0.9, where a
    reduction must be 2.6 to count: not a cause. Neither is one whose own move is within three standard errors."""
    agrees = Agreement(("frequency",), ("frequency",), reduction=3.0, se=0.5, needed=1.0)
    side_effect = Agreement(("frequency", "blocks"), ("frequency",), reduction=0.9, se=0.1, needed=2.6)
    noisy = Agreement(("color",), ("color",), reduction=1.2, se=0.5, needed=1.0)
    unmeasured = Agreement(("color",), ("color",), reduction=5.0, se=float("nan"), needed=1.0)
    assert agrees.agrees and agrees.describe() == ""
    assert not side_effect.agrees and not noisy.agrees and not unmeasured.agrees
    said = side_effect.describe()
    assert said == "not a cause: it lowers its own statistics (frequency, blocks) by +0.90 ± 0.10, less than a " + (
        "reduction must be to count (2.60)"
    )


@pytest.mark.slow  # two noise fits calibrated by simulation and the held-out statistics: about 20 s on one core
def test_noise_added_after_the_resampler_is_named_and_placed_after_it() -> None:
    """The camera adds strong white noise after its 2× upscale; the profile has the sensor's noise before it. The
    diagnosis adds a second noise source after the upscale, not before it."""
    camera = CameraProfile(None, [Noise(a=0.0002), Resolution(0.5), Noise(a=0.001)])
    profile = CameraProfile(None, [Noise(a=0.0002), Resolution(0.5)])
    cleans = scenes(16, 96, seed=5)
    reals = camera.simulate(cleans, 0, stream="camera")
    pairs = list(zip(cleans, reals))
    report = diagnose(
        profile,
        named("cal-", pairs[:8]),
        held_out=named("held-", pairs[8:]),
        candidates=["noise"],
        kinds=("add",),
        critic=False,
    )
    assert report.accepted[:1] == ["add noise"], report.verdict
    assert report.changes[0]["description"] == "adds noise after resolution", report.changes[0]
    assert [stage.name for stage in report.profile.effects] == ["noise", "resolution", "noise"]


def test_a_simpler_change_that_is_not_a_cause_does_not_go_first() -> None:
    """Removing a frequency response that leaves the texture too smooth does as well as refitting it 3.5× weaker;
    the removal is not a cause, so the refit stays first (and may be accepted)."""
    refit = Change("refit", "frequency_response", None, None, 9.2, 3.4, 0.4, True)
    removal = Change("remove", "frequency_response", None, None, 8.7, 3.9, 0.5, False, not_a_cause=True)
    assert prefer_simpler([refit, removal]) == [refit, removal]
    removal.not_a_cause = False
    assert prefer_simpler([refit, removal]) == [removal, refit]


def test_the_texture_a_change_is_judged_against_is_that_of_its_own_held_out_pairs() -> None:
    """One profile object diagnosed on two sets of pairs (a bench runs its scenarios in one process): each set's
    texture is its own, not the one measured first."""
    profile = CameraProfile(None, [])
    cleans = scenes(4, 48, seed=7)
    blurred = CameraProfile(None, [Blur(sigma_x=2.0)]).simulate(cleans, 0, stream="camera")
    sharp, soft = (HeldOut.build(list(zip(cleans, reals)), 0, "held-out") for reals in (cleans, blurred))
    assert _texture(sharp, profile).worst == 0.0
    assert _texture(soft, profile).worst > 1.0 and _texture(sharp, profile).worst == 0.0


def test_noise_before_a_codec_shows_as_the_codec_s_signature_too() -> None:
    """Noise before a JPEG stage changes its block edges and transfer: those are noise's own statistics there; a
    tone curve before it keeps its own, and noise after every mixing stage has only its own."""
    codec = [EFFECTS["jpeg"](quality=60)]
    assert own_families("add", "noise", codec) == ("noise", "noise_correlation", "banding", "frequency", "blocks")
    assert own_families("add", "tone", codec) == ("spatial", "intensity", "color")
    assert own_families("refit", "noise", [EFFECTS["tone"]()]) == ("noise", "noise_correlation", "banding")
