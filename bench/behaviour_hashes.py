"""Hashes of what camdegrade does, to show that a change of the house (modules moved, files split) changes no
behaviour: the built-in profiles' bytes, ``CameraDegrade`` outputs of each built-in on scikit-image photos (seeded),
the weights and the record of a small seeded fit, and a small diagnosis's JSON without its timings.

Run it in two trees and compare the two outputs (it imports whichever ``camdegrade`` is first on the path)::

    mkdir -p /tmp/before && git archive cb9cf0d src | tar -x -C /tmp/before
    PYTHONPATH=/tmp/before/src OMP_NUM_THREADS=1 .venv/bin/python bench/behaviour_hashes.py > /tmp/before.json
    PYTHONPATH=src OMP_NUM_THREADS=1 .venv/bin/python bench/behaviour_hashes.py > /tmp/after.json
    diff /tmp/before.json /tmp/after.json && echo same

Not part of ``make bench`` (it compares trees, it times nothing); a few minutes on one core.
"""

from __future__ import annotations

import hashlib
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import torch
from skimage import data

import camdegrade

PHOTOS = ("astronaut", "coffee", "chelsea", "rocket")
#: Keys of the diagnosis JSON that hold wall times (they differ from run to run, not with behaviour).
TIMING_KEYS = ("seconds", "elapsed", "time", "minutes")


def digest(value: bytes) -> str:
    return hashlib.sha256(value).hexdigest()[:16]


def tensor_digest(tensor: torch.Tensor) -> str:
    return digest(tensor.detach().contiguous().cpu().numpy().tobytes())


def photos(side: int = 96) -> torch.Tensor:
    images = [torch.from_numpy(np.ascontiguousarray(getattr(data, name)()[:side, :side, :3])) for name in PHOTOS]
    return torch.stack(images).permute(0, 3, 1, 2).contiguous()


def builtin_hashes() -> dict[str, Any]:
    out = {}
    for name in camdegrade.list_profiles():
        path = Path(camdegrade.__file__).parent / "profiles" / f"{name}.safetensors"
        transform = camdegrade.CameraDegrade(name, seed=7)
        out[name] = {"file": digest(path.read_bytes()), "outputs": tensor_digest(transform(photos()))}
    return out


def without_timings(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: without_timings(v) for k, v in value.items() if not any(t in k for t in TIMING_KEYS)}
    if isinstance(value, list):
        return [without_timings(v) for v in value]
    return value


def fit_and_diagnose(folder: Path) -> dict[str, Any]:
    from camdegrade.fitting import FitConfig

    clean = folder / "photos"
    clean.mkdir()
    from PIL import Image

    for index, image in enumerate(photos(128)):
        Image.fromarray(image.permute(1, 2, 0).numpy()).save(clean / f"{index}.png")
        Image.fromarray(image.flip(-1).permute(1, 2, 0).numpy()).save(clean / f"{index}f.png")
    camdegrade.simulate_pairs("lowcost-robot", clean, folder / "pairs", seed=3)
    config = FitConfig.recipe("fast").replace(epochs=2, seed=0)
    profile = camdegrade.fit_profile(folder / "pairs", config)
    weights = {key: tensor_digest(value) for key, value in sorted(profile.state_dict().items())}
    record = without_timings(json.loads(json.dumps(profile.metadata().get("fitted", {}), default=str)))
    report = camdegrade.diagnose(profile, folder / "pairs", seed=0, critic=False, max_added=1)
    diagnosis = without_timings(json.loads(report.to_json()))
    return {
        "fit_weights": weights,
        "fit_record": digest(json.dumps(record, sort_keys=True).encode()),
        "diagnosis": digest(json.dumps(diagnosis, sort_keys=True).encode()),
    }


def main() -> None:
    torch.set_num_threads(1)
    out: dict[str, Any] = {"camdegrade": str(Path(camdegrade.__file__).parent), "builtins": builtin_hashes()}
    with tempfile.TemporaryDirectory() as folder:
        out |= fit_and_diagnose(Path(folder))
    out.pop("camdegrade")
    json.dump(out, sys.stdout, indent=1, sort_keys=True)
    print()


if __name__ == "__main__":
    main()
