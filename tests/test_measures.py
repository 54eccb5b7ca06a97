"""The statistic families' registry (camdegrade.measures): every family states its facts on its class, every name an
effect uses is a registered family, no family fact lives outside the registry, and a new family is one class."""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch
from torch import Tensor

import camdegrade
from camdegrade.diagnose.report import DiagnosisReport
from camdegrade.diagnose.where import findings
from camdegrade.effects import EFFECTS
from camdegrade.measures import (
    FAMILIES,
    NO_REFERENCE,
    MeasuredPair,
    NoReferenceFamily,
    PairedFamily,
    StatisticSet,
    family_gaps,
    image_statistics,
    pair_statistics,
    register_family,
)
from effects_images import photo

PACKAGE = Path(camdegrade.__file__).parent
NAMES = set(FAMILIES) | set(NO_REFERENCE)
#: Effect names that are no family's name.
EFFECT_ONLY = set(EFFECTS) - NAMES


def _pair(height: int, width: int, seed: int) -> tuple[Tensor, Tensor]:
    clean = photo("astronaut", max(height, width))[:, :height, :width].clamp(0, 1)
    noise = torch.randn(clean.shape, generator=torch.Generator().manual_seed(seed)) * 0.01
    return (clean * 0.9 + 0.05 + noise).clamp(0, 1), clean


@pytest.mark.parametrize("name", list(FAMILIES))
def test_every_paired_family_states_its_facts(name: str) -> None:
    family = FAMILIES[name]
    assert family.name == name and family.paired and isinstance(family, PairedFamily)
    assert family.tau > 0 and family.unit and family.description and "\n" not in family.description
    assert isinstance(family.network_fault, str)
    shapes = []
    for height, width in ((64, 64), (48, 80)):  # sums of every pair have one shape: they are stacked over pairs
        image, clean = _pair(height, width, seed=height)
        num, den = family.measure(MeasuredPair(image, clean))
        assert num.dtype == den.dtype == torch.float32
        shapes.append((num.shape, den.shape))
    assert shapes[0] == shapes[1]
    values = family.reduce(num.double(), den.double()).flatten()
    assert values.ndim == 1 and values.numel() > 0
    assert family.compare(values).shape == values.shape
    stats = StatisticSet.measure([image], [clean], [MeasuredPair(image, clean).mask])
    text = family.describe(values.float(), values.float(), stats)
    assert isinstance(text, str) and text and "\n" not in text


@pytest.mark.parametrize("name", list(NO_REFERENCE))
def test_every_no_reference_family_states_its_facts(name: str) -> None:
    family = NO_REFERENCE[name]
    assert family.name == name and not family.paired and isinstance(family, NoReferenceFamily)
    assert family.tau > 0 and family.unit and family.description
    assert family.signature in FAMILIES, "it carries the signature of a paired family"
    assert family.suspects() == FAMILIES[family.signature].suspects()
    lengths = {family.measure(_pair(height, width, seed=0)[0]).shape for height, width in ((64, 64), (48, 80))}
    assert len(lengths) == 1 and len(next(iter(lengths))) == 1


def test_every_name_an_effect_uses_is_a_registered_family() -> None:
    for name, cls in EFFECTS.items():
        assert set(cls.explains) <= set(FAMILIES), (name, cls.explains)


def test_suspects_are_the_effects_that_name_the_family() -> None:
    assert "noise" in FAMILIES["noise"].suspects() and "blur" in FAMILIES["frequency"].suspects()
    assert "noise" not in FAMILIES["frequency"].suspects()
    assert {name for name, family in FAMILIES.items() if family.network_fault} == {"blocks", "frequency"}


def _family_facts(tree: ast.AST) -> list[str]:
    """Literal collections (tuple, list, set, dict keys) naming two or more registered families, and family names
    compared with ``==``/``in``: a family fact (a list of families, a per-family table) kept outside the registry.
    An effect's ``explains`` is how effects name the families they explain, and is allowed."""
    allowed = {
        id(node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "explains" for t in node.targets)
    }
    found = []
    for node in ast.walk(tree):
        if id(node) in allowed:
            continue
        items = node.keys if isinstance(node, ast.Dict) else getattr(node, "elts", None)
        if isinstance(node, (ast.Tuple, ast.List, ast.Set, ast.Dict)) and items is not None:
            constants = [i.value for i in items if isinstance(i, ast.Constant)]
            names = [value for value in constants if value in NAMES]
            # A table of effects (blur, jpeg, ...) names the effects called like families (color, noise, tone).
            if len(names) >= 2 and not EFFECT_ONLY.intersection(constants):
                found.append(", ".join(names))
        if isinstance(node, ast.Compare):
            found += [
                operand.value
                for operand in [node.left, *node.comparators]
                if isinstance(operand, ast.Constant) and operand.value in NAMES
            ]
    return found


def test_no_family_fact_lives_outside_the_registry() -> None:
    offenders = {}
    for path in PACKAGE.rglob("*.py"):
        if "measures" in path.relative_to(PACKAGE).parts:
            continue
        facts = _family_facts(ast.parse(path.read_text()))
        if facts:
            offenders[str(path.relative_to(PACKAGE))] = facts
    assert not offenders


def test_the_family_fact_check_can_fail() -> None:
    assert _family_facts(ast.parse('TAU = {"radial": 0.01, "tone": 0.01}')) == ["radial, tone"]
    assert _family_facts(ast.parse('SIGNATURES = ("blocks", "frequency")')) == ["blocks, frequency"]
    assert _family_facts(ast.parse('FACTS = {"blur": 1, "color": 2, "noise": 3}')) == []  # an effect table
    assert _family_facts(ast.parse('if axis == "banding": pass')) == ["banding"]
    assert _family_facts(ast.parse('class Blur:\n    explains = ("frequency", "alignment")')) == []


class _Saturation(PairedFamily):
    """A family a test adds: the share of clipped pixels, image minus clean."""

    name = "saturation_for_tests"
    tau = 0.01
    unit = "share of pixels"
    description = "share of pixels at 0 or 1, image minus clean"

    def measure(self, pair: MeasuredPair) -> tuple[Tensor, Tensor]:
        clipped = [((x <= 0) | (x >= 1)).float().mean() for x in (pair.image, pair.clean)]
        return (clipped[0] - clipped[1])[None], torch.ones(1)

    def reduce(self, num: Tensor, den: Tensor) -> Tensor:
        return num / den

    def describe(self, real: Tensor, sim: Tensor, real_set: StatisticSet) -> str:
        return f"clipped share real {float(real[0]):+.3f} vs sim {float(sim[0]):+.3f}"


class _Brightness(NoReferenceFamily):
    name = "brightness_for_tests"
    tau = 0.01
    unit = "mean"
    description = "mean value"
    signature = "intensity"

    def measure(self, image: Tensor) -> Tensor:
        return image.mean()[None]


@pytest.fixture
def new_families() -> Iterator[None]:
    register_family(_Saturation)
    register_family(_Brightness)
    yield
    del FAMILIES[_Saturation.name], NO_REFERENCE[_Brightness.name]


@pytest.mark.usefixtures("new_families")
def test_a_new_family_is_one_class_and_reaches_every_report() -> None:
    image, clean = _pair(64, 64, seed=1)
    brighter = (image + 0.2).clamp(0, 1)
    assert _Saturation.name in pair_statistics(image, clean) and _Brightness.name in image_statistics(image)
    mask = MeasuredPair(image, clean).mask
    real, sim = StatisticSet.measure([brighter], [clean], [mask]), StatisticSet.measure([image], [clean], [mask])
    scores = family_gaps(real, sim)
    assert scores[_Saturation.name] > 1.0
    where = findings(real, sim, scores, {})
    entry = next(entry for entry in where if entry["axis"] == _Saturation.name)
    assert entry["finding"].startswith("clipped share real") and "[suspects: the network]" in entry["finding"]
    report = DiagnosisReport(0.0, 0.0, 0.0, where, [], [])
    assert report.to_dict()["family_tau"][_Saturation.name] == 0.01


def test_a_second_family_of_one_name_is_refused() -> None:
    class Again(PairedFamily):
        name = "noise"
        tau = 1.0

    with pytest.raises(ValueError, match="already registered"):
        register_family(Again)


def test_a_diagnosis_refuses_an_effect_naming_an_unknown_family() -> None:
    from camdegrade.diagnose import diagnose
    from camdegrade.effects import Effect, register_effect

    class Misspelt(Effect):
        name = "misspelt_for_tests"
        explains = ("nosie",)

    register_effect(Misspelt)
    try:
        with pytest.raises(ValueError, match=r"Misspelt.explains must hold statistic family names .* \['nosie'\]"):
            diagnose("city100-iphonex", [])
    finally:
        del EFFECTS[Misspelt.name]


class _Values:
    """Stands in for a StatisticSet: pooled noise std and row-mean std per flat-pixel bin (levels)."""

    def __init__(self, std: float, lines: float) -> None:
        self.std, self.lines = std, lines

    def values(self) -> dict[str, Tensor]:
        return {"noise": torch.full((4,), self.std), "banding": torch.full((4,), self.lines)}


def test_a_noise_stage_on_a_camera_without_noise_is_named_as_such_not_as_a_huge_ratio() -> None:
    """Issue 26: flat constant captures hold no noise; the old text read "noise stage is 99047.0× the camera's"."""
    from camdegrade.measures.families.noise import noise_stage_text

    text = noise_stage_text("noise", _Values(1e-5, 0.0), _Values(1.5, 0.4))
    assert text == "noise stage adds noise where the camera shows none (1.50 levels on its flat pixels)"
    assert noise_stage_text("noise", _Values(1.0, 0.3), _Values(4.0, 0.9)) == (
        "noise stage is 4.0× the camera's noise and banded (row means 3.0× the camera's)"
    )
    assert noise_stage_text("noise", _Values(float("nan"), 0.0), _Values(1.5, 0.4)) == "noise stage"  # not measured
