"""The diagnosis' critic: what it sees in the report (its surest patches, its accuracy by group)."""

from __future__ import annotations

import base64
import io
import json
import re

import pytest
import torch
from PIL import Image

from camdegrade.diagnose import DiagnosisReport, diagnose
from camdegrade.diagnose._html import png_url
from camdegrade.diagnose.critic_html import DETAIL_GAIN
from camdegrade.effects import Noise, Tone
from camdegrade.measures.critic import PATCH
from camdegrade.measures.critic_explain import GROUPINGS, surest_png
from camdegrade.profile import CameraProfile
from camdegrade.sim import VirtualCamera
from effects_images import patch_chart, photo

torch.set_num_threads(1)


def scenes(count: int, size: int, seed: int) -> list[torch.Tensor]:
    """Photo crops and patch charts, different per seed."""
    generator = torch.Generator().manual_seed(seed)
    names = ("astronaut", "coffee", "chelsea")
    out = []
    for index in range(count):
        if index % 3 == 2:
            out.append(patch_chart(size, patches=max(1, size // 48), seed=seed * 100 + index))
            continue
        full = photo(names[index % 3], 3 * size)
        top, left = (int(torch.randint(0, side - size + 1, (1,), generator=generator)) for side in full.shape[-2:])
        out.append(full[:, top : top + size, left : left + size].clamp(0, 1))
    return out


def camera_pairs(camera: VirtualCamera, count: int, size: int, seed: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
    generator = torch.Generator().manual_seed(seed + 1)
    with torch.no_grad():
        return [(clean, camera(clean[None], generator=generator)[0]) for clean in scenes(count, size, seed)]


@pytest.fixture(scope="module")
def toned() -> DiagnosisReport:
    """A camera with a tone curve, a profile without: the critic tells most patches apart before, fewer after."""
    camera = VirtualCamera([Noise(a=0.0005), Tone(gamma=1.3, black=0.03)], scale=1.0)
    profile = CameraProfile(None, [Noise(a=0.0005)], name="no-tone")
    return diagnose(
        profile,
        camera_pairs(camera, 6, 64, seed=0),
        held_out=camera_pairs(camera, 6, 64, seed=1),
        candidates=["tone"],
        kinds=("add",),
    )


def test_the_json_carries_the_accuracy_by_group_and_the_surest_patches(toned: DiagnosisReport, tmp_path) -> None:
    data = json.loads(toned.write_json(tmp_path / "r.json").read_text())
    assert data["accepted"] == ["add tone"]
    for label in ("before", "after"):
        critic = data["critic"][label]
        assert list(critic["by_group"]) == list(GROUPINGS)
        for grouping, tiers in critic["by_group"].items():
            assert sum(tier["patches"] for tier in tiers.values()) == critic["patches"], grouping
            right = sum(tier["accuracy"] * tier["patches"] for tier in tiers.values() if tier["patches"])
            assert right / critic["patches"] == pytest.approx(critic["accuracy"], abs=1e-3)
        assert {entry["label"] for entry in critic["surest"]} == {"real", "simulated"}
        assert set(critic["group_edges"]) == set(GROUPINGS)
    assert data["critic"]["before"]["accuracy"] > 0.9
    assert data["critic"]["after"]["accuracy"] < data["critic"]["before"]["accuracy"]


def test_the_html_shows_the_surest_patches_real_beside_simulated_and_the_table(toned: DiagnosisReport) -> None:
    page = toned.to_html()
    for label in ("before", "after"):
        patches = toned.critic_surest[label]
        assert patches and {p.label for p in patches} == {"real", "simulated"}
        names = toned.critic[label]["scored_on"]
        url = png_url(surest_png(patches, scale=2, names=names, detail_gain=DETAIL_GAIN))
        assert url in page, label
        picture = Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1])))
        assert picture.height >= len([p for p in patches if p.label == "real"]) * 2 * PATCH  # 2x
        assert f"Profile {label}: the held-out patches the critic is surest about" in page
    assert "Where it decides" in page
    table = page[page.index("Where it decides") :]
    for grouping, (_, names) in GROUPINGS.items():
        assert f"<td>{grouping}</td>" in table
        assert re.search(rf"<td>{names[0]} (\d\.\d\d|n/a) \(\d+\)</td>", table), grouping
