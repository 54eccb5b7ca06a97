"""The pair set both workflows start from: loading (bad files reported, not fatal), scene split, seeded simulation."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from camdegrade import CameraProfile
from camdegrade._runtime.outputs import OUTPUTS
from camdegrade._support.seeds import derived_generator
from camdegrade.effects import Noise, Tone
from camdegrade.errors import PairsError
from camdegrade.io import write_image
from camdegrade.network import LocalAffineNet
from camdegrade.pairs.pairset import PairSet


def _image(seed: int, size: int = 24) -> torch.Tensor:
    return torch.randint(0, 256, (3, size, size), dtype=torch.uint8, generator=torch.Generator().manual_seed(seed))


def _folder(root: Path, count: int) -> Path:
    for index in range(count):
        write_image(_image(index), root / "clean" / f"s{index // 2}_{index}.png")
        write_image(_image(100 + index), root / "captured" / f"s{index // 2}_{index}.png")
    return root


def _truncate(path: Path) -> None:
    """Keep the PNG header (the size still reads) but cut the image data short."""
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def test_loads_a_folder_and_reports_a_file_that_does_not_decode(tmp_path: Path) -> None:
    root = _folder(tmp_path, 6)
    _truncate(root / "captured" / "s1_3.png")
    lines: list[str] = []
    pair_set = PairSet.load(root, log=lines.append)
    assert len(pair_set) == 5 and "s1_3" not in pair_set.names
    assert pair_set.report is not None and len(pair_set.report.pairs) == 5
    assert any("s1_3.png" in str(path) and reason.startswith("unreadable") for path, reason in pair_set.report.skipped)
    assert "unreadable" in lines[-1]
    assert all(clean.dtype == torch.uint8 for clean, _ in pair_set.images)
    assert all(clean.dtype == torch.float32 and float(clean.max()) <= 1 for clean, _ in pair_set.unit_pairs())


def test_no_loadable_pair_is_an_error_that_lists_the_files(tmp_path: Path) -> None:
    root = _folder(tmp_path, 1)
    _truncate(root / "clean" / "s0_0.png")
    with pytest.raises(PairsError, match="no pair could be loaded"):
        PairSet.load(root)


def test_tensor_pairs_and_their_errors() -> None:
    image = torch.rand(3, 8, 8)
    pair_set = PairSet.load([(image, image), (image, image)], max_pairs=1)
    assert len(pair_set) == 1 and pair_set.scenes == ["0"]
    with pytest.raises(ValueError, match=r"pair 0: clean and captured must be \(3, H, W\) of the same size"):
        PairSet.load([(image, image[:, :4])])
    with pytest.raises(TypeError, match="pairs must be a folder or CSV path"):
        PairSet.load(["a", "b"])
    with pytest.raises(ValueError, match="max_pairs must be a positive integer or None, got max_pairs=0"):
        PairSet.load([(image, image)], max_pairs=0)


def test_split_keeps_every_scene_on_one_side(tmp_path: Path) -> None:
    root = _folder(tmp_path, 8)
    rows = [f"clean/s{i // 2}_{i}.png,captured/s{i // 2}_{i}.png,s{i // 2}" for i in range(8)]
    (root / "pairs.csv").write_text("clean,captured,scene\n" + "\n".join(rows) + "\n")
    pair_set = PairSet.load(root / "pairs.csv")
    assert sorted(set(pair_set.scenes)) == ["s0", "s1", "s2", "s3"]
    rest, held = pair_set.split(0.5, seed=3)
    assert sorted(rest.names + held.names) == sorted(pair_set.names)
    assert not set(rest.scenes) & set(held.scenes) and len(set(held.scenes)) == 2
    assert pair_set.split(0.5, seed=3)[1].names == held.names


def test_simulation_is_seeded_per_image_and_stream() -> None:
    profile = CameraProfile(None, [Noise(a=0.01, b=1e-4), Tone(gamma=1.2)])
    cleans = [torch.rand(3, 16, 16, generator=torch.Generator().manual_seed(i)) for i in range(3)]
    first = profile.simulate(cleans, seed=1)
    assert all(torch.equal(a, b) for a, b in zip(first, profile.simulate(cleans, seed=1), strict=True))
    assert torch.equal(profile.simulate(cleans[:1], seed=1)[0], first[0])  # an image's draw ignores the others
    assert not torch.equal(profile.simulate(cleans, seed=1, stream="other")[0], first[0])
    assert not torch.equal(profile.simulate(cleans, seed=2)[0], first[0])
    mean = profile.simulate(cleans, seed=1, deterministic=True)
    assert torch.allclose(mean[0], Tone(gamma=1.2)(cleans[0][None])[0], atol=1e-6)


def test_deterministic_part_keeps_the_metadata() -> None:
    profile = CameraProfile(None, [Noise(a=0.01), Tone(gamma=1.2)], fitted={"pairs": 3}, quality={"psnr": 30.0})
    centre = profile.without_randomness()
    assert centre.effect_names == ["tone"] and centre.fitted == {"pairs": 3} and centre.quality == {"psnr": 30.0}


def _profile_with_network(noise: bool) -> CameraProfile:
    network = LocalAffineNet(8)
    with torch.no_grad():
        for parameter in network.parameters():
            parameter.add_(torch.randn(parameter.shape, generator=torch.Generator().manual_seed(5)) * 0.05)
    return CameraProfile(network, [*([Noise(a=0.01)] if noise else []), Tone(gamma=1.2)])


def _direct(profile: CameraProfile, cleans: list[torch.Tensor], seed: int, stream: str) -> list[torch.Tensor]:
    """What the profile itself gives each image, seeded as :meth:`CameraProfile.simulate` seeds it."""
    with torch.no_grad():
        return [
            profile(clean[None], profile.make_params((1, *clean.shape), derived_generator(seed, stream, index)))[0]
            for index, clean in enumerate(cleans)
        ]


def _same(first: list[torch.Tensor], second: list[torch.Tensor]) -> bool:
    return all(torch.equal(a, b) for a, b in zip(first, second, strict=True))


@pytest.mark.parametrize("noise", [False, True])
def test_simulations_taken_again_are_the_bytes_computed_once(noise: bool) -> None:
    """A profile that draws nothing is simulated once per image; one that draws reuses its network's output. Either
    way every call gives what the profile itself gives, for any seed and stream; an image or a weight changed in
    place is simulated anew, and nothing outlives the images it was computed for."""
    profile = _profile_with_network(noise)
    cleans = [torch.rand(3, 20, 28, generator=torch.Generator().manual_seed(i)) for i in range(3)]
    OUTPUTS.clear()
    for seed, stream in ((0, "simulate"), (0, "simulate"), (3, "other"), (0, "simulate")):
        assert _same(profile.simulate(cleans, seed, stream=stream), _direct(profile, cleans, seed, stream))
    assert len(OUTPUTS) == 3  # one entry per image: the network's output, or the whole profile's
    cleans[1].mul_(0.5)
    with torch.no_grad():
        profile.network.linear.bias.add_(0.02)
    assert _same(profile.simulate(cleans, 0), _direct(profile, cleans, 0, "simulate"))
    assert len(OUTPUTS) == 6
    cleans.clear()
    assert len(OUTPUTS) == 0
