"""The diagnosis' two findings (:mod:`camdegrade.diagnose.attribution.attribute`): the profile's own misfit (changes to
what it has) apart from the effects it lacks, and a missing effect that a large misfit hid, found once the misfit is
fixed.

The search is a stub here (no images): it returns the changes a real search returned on the suite's
``underfit-chromatic_aberration`` scenario (``bench/bench_diagnose.py``: a blur stage half as wide as the camera's
and chromatic aberration withheld), where chromatic aberration alone was not significant beside the misfit."""

from __future__ import annotations

from types import SimpleNamespace

from camdegrade.diagnose.attribution.attribute import Attribution, _grow
from camdegrade.diagnose.attribution.changes import Change
from camdegrade.diagnose.core import _missing_rows
from camdegrade.diagnose.verdict import finding_sentence
from camdegrade.profile import CameraProfile


def _change(kind: str, name: str, gap: float, reduction: float, significant: bool, before=()) -> Change:
    return Change(kind, name, CameraProfile(None, []), None, gap, reduction, 0.5, significant, before=list(before))


class StubSearch:
    """Answers each round with fixed changes and records which changes each round was allowed to try."""

    def __init__(self, rounds: list[list[Change]]) -> None:
        self.rounds = rounds
        self.allowed: list[set | None] = []
        self.kinds = {"add", "remove", "refit", "network"}
        self.baseline = SimpleNamespace(significant=True)
        self.held = SimpleNamespace(statistics=lambda profile: (None, None))

    def changes(self, current, stats, gap_now, before, allowed, adds, say) -> list[Change]:
        self.allowed.append(allowed)
        return [_change(c.kind, c.name, c.gap_after, c.reduction, c.significant, before) for c in self.rounds.pop(0)]


ADDS = ["chromatic_aberration", "color", "noise"]


def test_a_missing_effect_hidden_by_the_misfit_is_tried_and_found_on_top_of_it() -> None:
    singles = [
        _change("refit", "blur", 3.0, 14.6, True),
        _change("add", "chromatic_aberration", 15.5, 2.15, False),  # hidden: not significant beside the misfit
        _change("refit", "jpeg", 15.7, 1.9, False),
    ]
    search = StubSearch(
        [[_change("add", "chromatic_aberration", 1.7, 1.3, True), _change("add", "color", 3.0, 0.0, False)]]
    )
    accepted, combinations = _grow(search, singles, ADDS, 3, lambda line: None)
    assert ("add", "chromatic_aberration") in search.allowed[0] and ("add", "color") in search.allowed[0]
    assert [c.label for c in accepted] == ["refit blur", "add chromatic_aberration"]
    result = Attribution(None, None, singles, combinations, accepted, None, None, [], 0.0)  # type: ignore[arg-type]
    assert [c.label for c in result.misfit] == ["refit blur"]
    assert [c.label for c in result.missing] == ["add chromatic_aberration"]
    assert [c.label for c in result.missing_ranking] == ["add chromatic_aberration", "add color"]
    rows = _missing_rows(result)
    assert [(row["name"], row["accepted"]) for row in rows] == [("chromatic_aberration", True), ("color", False)]


def test_once_an_effect_is_added_only_the_significant_changes_are_tried_again() -> None:
    singles = [_change("add", "color", 3.0, 12.9, True), _change("refit", "blur", 3.6, 12.2, True)]
    search = StubSearch([[_change("refit", "blur", 1.2, 1.8, True, ["add color"])]])
    accepted, _ = _grow(search, singles, ADDS, 3, lambda line: None)
    assert search.allowed == [{("refit", "blur")}]  # the first accepted change named the missing effect itself
    assert [c.label for c in accepted] == ["add color", "refit blur"]
    result = Attribution(None, None, singles, [], accepted, None, None, [], 0.0)  # type: ignore[arg-type]
    assert [c.label for c in result.missing_ranking] == ["add color"]  # ranked alone: no misfit came first


def test_a_misfit_with_nothing_missing_is_its_own_finding() -> None:
    singles = [_change("refit", "blur", 1.3, 14.9, True), _change("add", "jpeg", 15.6, 0.6, False)]
    search = StubSearch([[_change("add", "jpeg", 1.3, 0.0, False), _change("add", "noise", 1.4, -0.1, False)]])
    accepted, combinations = _grow(search, singles, ADDS, 3, lambda line: None)
    assert [c.label for c in accepted] == ["refit blur"]
    result = Attribution(None, None, singles, combinations, accepted, None, None, [], 0.0)  # type: ignore[arg-type]
    assert result.missing == [] and [row["accepted"] for row in _missing_rows(result)] == [False, False]


def test_the_findings_in_words() -> None:
    refit = _change("refit", "blur", 3.0, 14.6, True)
    refit.description = "blur stage is 2.0× too weak"
    added = _change("add", "chromatic_aberration", 1.7, 1.3, True)
    assert finding_sentence(True, [refit], "p") == (
        "The profile does not reproduce the camera: the profile's blur stage is 2.0× too weak; fix: refitting blur "
        "(gap −14.60)."
    )
    assert finding_sentence(False, [added], "p") == (
        "The camera has an effect the profile lacks: chromatic_aberration; fix: adding chromatic_aberration "
        "(gap −1.30)."
    )


def test_an_effect_the_network_fine_tune_would_absorb_is_named_first() -> None:
    """The suite's ``network-checkerboard-color``: the fine-tune alone leaves 4.58 (it learns the colour cast too);
    adding colour first and fine-tuning on top leaves 1.95, so colour is the missing effect and the network the
    misfit."""
    singles = [
        _change("network", "network", 4.58, 24.39, True),
        _change("add", "color", 15.24, 13.73, True),
        _change("refit", "noise", 27.15, 1.83, True),
    ]
    search = StubSearch([[_change("network", "network", 1.95, 13.29, True)], []])
    accepted, combinations = _grow(search, singles, ADDS, 3, lambda line: None)
    assert search.allowed[0] == {("network", "network")}  # the trial: the fine-tune on top of colour only
    assert [c.label for c in accepted] == ["add color", "network network"]
    assert [c.before[-1].label for c in combinations[:1]] == ["add color"]


def test_a_stage_refitted_to_hide_the_network_artefact_is_not_named_first() -> None:
    """When the fine-tune on top of the best added effect ends further from the camera than the fine-tune alone
    (the effect only compensated the network's artefact), the fine-tune is accepted first."""
    singles = [_change("network", "network", 1.44, 12.75, True), _change("add", "denoise", 9.85, 4.33, True)]
    search = StubSearch([[_change("network", "network", 3.0, 6.85, True)], []])
    accepted, _ = _grow(search, singles, ADDS, 3, lambda line: None)
    assert accepted[0].label == "network network"


def test_the_report_carries_both_findings_in_json_and_html() -> None:
    from camdegrade.diagnose.report import DiagnosisReport, render_html

    misfit = [{"kind": "refit", "name": "blur", "gap_after": 3.02, "reduction": 14.6, "description": "too weak"}]
    missing = [
        {
            "kind": "add",
            "name": "chromatic_aberration",
            "gap_after": 1.82,
            "reduction": 1.2,
            "reduction_se": 0.14,
            "accepted": True,
        },
        {"kind": "add", "name": "color", "gap_after": 3.0, "reduction": 0.0, "reduction_se": None, "accepted": False},
    ]
    report = DiagnosisReport(17.6, 1.8, 1.3, [], [], ["chromatic_aberration"], misfit=misfit, missing=missing)
    data = report.to_dict()
    assert data["misfit"] == misfit and [row["accepted"] for row in data["missing"]] == [True, False]
    page = render_html(report)
    own, lacks = page.index("The profile's own misfit"), page.index("ranked (once the misfit is fixed)")
    assert own < page.index("refit blur") < lacks < page.index("add chromatic_aberration") < page.index("add color")
