"""A virtual camera: a chain of effect stages with named presets, and synthetic (clean, captured) pair folders.

The virtual camera gives pairs with known ground truth: for demos, for tests of the fitters and the diagnosis,
and for validating a training pipeline before real captures exist.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from camdegrade._support.checks import check_int, check_seed
from camdegrade._support.files import atomic_path, check_outputs_spare_inputs
from camdegrade._support.pixels import as_unit, unit_to_bytes
from camdegrade._support.seeds import derived_generator
from camdegrade.effects import EFFECTS, STAGES, Effect
from camdegrade.effects.chain import apply_effects, check_chain, check_params
from camdegrade.errors import BatchError, UnknownPresetError
from camdegrade.functional.optics.geometry import shrink_to_max_side
from camdegrade.io import input_images, read_image, write_image

__all__ = ["PRESETS", "CameraParams", "Preset", "VirtualCamera", "simulate_pairs"]

CameraParams = list[dict[str, Tensor]]


@dataclass(frozen=True)
class Preset:
    """A named virtual camera: ``scale`` (sensor resolution relative to the input) and effect specs."""

    description: str
    scale: float
    effects: tuple[tuple[str, Mapping[str, Any]], ...] = field(default_factory=tuple)


_ROBOT_COLOR = [[1.05, 0.06, -0.02], [0.02, 1.0, 0.0], [-0.03, 0.10, 0.80]]
_ROBOT_OPTICS: tuple[tuple[str, Mapping[str, Any]], ...] = (
    ("distortion", {"k1": 0.06}),
    ("chromatic_aberration", {"red": 0.0015, "blue": -0.001}),
    ("vignetting", {"k1": -0.35, "k2": 0.05}),
    ("blur", {"sigma_x": 1.0}),
)

#: Named virtual cameras. ``lowcost-robot`` is the paper's setting; ``-wild`` adds per-shot variation.
PRESETS: dict[str, Preset] = {
    "lowcost-robot": Preset(
        "cheap USB/robot camera: half resolution, soft barrel lens with vignetting, visible sensor noise with "
        "row banding, greenish-warm cast, lifted blacks and clipped highlights, JPEG quality 45",
        scale=0.5,
        effects=(
            *_ROBOT_OPTICS,
            ("noise", {"a": 0.003, "b": 5e-6, "row_sigma": 0.0015}),
            ("color", {"matrix": _ROBOT_COLOR}),
            ("tone", {"gamma": 1.1, "black": -0.04, "white": 0.92}),
            ("jpeg", {"quality": 45}),
        ),
    ),
    "lowcost-robot-wild": Preset(
        "lowcost-robot with per-shot variation for an 'in the wild' test set: auto-exposure (±0.35 EV), "
        "white balance (±8 %), sensor gain (±30 %) and JPEG quality (±10)",
        scale=0.5,
        effects=(
            *_ROBOT_OPTICS,
            ("noise", {"a": 0.003, "b": 5e-6, "row_sigma": 0.0015, "gain_jitter": 0.3}),
            ("color", {"matrix": _ROBOT_COLOR, "gain_jitter": 0.08}),
            ("tone", {"gamma": 1.1, "black": -0.04, "white": 0.92, "exposure_jitter": 0.35}),
            ("jpeg", {"quality": 45, "quality_jitter": 10}),
        ),
    ),
    "phone-indoor": Preset(
        "mid-range phone indoors: full resolution, slight lens softness and vignetting, mild noise, "
        "tungsten cast, gentle tone curve, JPEG quality 85",
        scale=1.0,
        effects=(
            ("vignetting", {"k1": -0.15}),
            ("blur", {"sigma_x": 0.5}),
            ("noise", {"a": 0.0015, "b": 2e-6}),
            ("color", {"matrix": [[1.06, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.9]]}),
            ("tone", {"gamma": 1.03, "black": 0.01, "white": 0.98}),
            ("jpeg", {"quality": 85}),
        ),
    ),
}


class VirtualCamera(nn.Module):
    """Turn clean images into captures: optics stages at the input resolution, then the sensor samples at
    ``scale`` of it, sensor/ISP/codec stages run there, and the result is upsampled back to the input size
    (bicubic), so (clean, captured) pairs stay pixel-aligned.

    Args:
        effects: stages in physical order (optics → sensor → ISP → codec).
        scale: sensor resolution relative to the input, in (0, 1]; 1 keeps the resolution.
        name: a label (the preset name for :meth:`from_preset`).

    Randomness is drawn in :meth:`make_params` (one dict per stage, as a profile does), so a capture replays
    exactly given the same generator seed.

    Examples:
        >>> camera = VirtualCamera.from_preset("phone-indoor")
        >>> clean = torch.rand(2, 3, 32, 48, generator=torch.Generator().manual_seed(0))
        >>> camera(clean, generator=torch.Generator().manual_seed(1)).shape
        torch.Size([2, 3, 32, 48])
    """

    def __init__(self, effects: Sequence[Effect], *, scale: float = 1.0, name: str = "") -> None:
        super().__init__()
        check_chain(effects, ordered=True)
        if not 0.0 < float(scale) <= 1.0:
            raise ValueError(f"scale must be in (0, 1], got scale={scale!r}")
        self.effects = nn.ModuleList(effects)
        self.scale = float(scale)
        self.name = name
        # The sensor samples after the last optics stage.
        ranks = [STAGES.index(effect.stage) for effect in effects]
        self._sensor_index = next((i for i, rank in enumerate(ranks) if rank > 0), len(ranks))

    @classmethod
    def from_preset(cls, name: str) -> VirtualCamera:
        """The virtual camera of a named preset (see :data:`PRESETS`)."""
        if name not in PRESETS:
            raise UnknownPresetError(f"unknown preset {name!r}; known presets: {', '.join(sorted(PRESETS))}")
        preset = PRESETS[name]
        return cls(
            [EFFECTS[effect](**dict(kwargs)) for effect, kwargs in preset.effects], scale=preset.scale, name=name
        )

    def sensor_size(self, height: int, width: int) -> tuple[int, int]:
        """The resolution at which the sensor/ISP/codec stages run for an input of ``height × width``."""
        return max(1, round(height * self.scale)), max(1, round(width * self.scale))

    def make_params(self, shape: torch.Size | Sequence[int], generator: torch.Generator | None = None) -> CameraParams:
        """Draw every stage's random values for a batch of ``shape = (N, 3, H, W)``, in chain order."""
        n, channels, height, width = (int(size) for size in shape)
        low = (n, channels, *self.sensor_size(height, width))
        full = (n, channels, height, width)
        return [
            effect.make_params(full if index < self._sensor_index else low, generator)
            for index, effect in enumerate(self.effects)
        ]

    def forward(
        self, image: Tensor, params: CameraParams | None = None, generator: torch.Generator | None = None
    ) -> Tensor:
        """Capture ``image`` (``(N, 3, H, W)`` or ``(3, H, W)``, uint8 or float in [0, 1]); same shape and dtype.

        ``params`` replays a previous draw; otherwise they are drawn from ``generator`` (``None``: torch's
        global RNG).
        """
        if image.ndim not in (3, 4) or image.shape[-3] != 3:
            raise ValueError(f"image must have shape (3, H, W) or (N, 3, H, W), got shape {tuple(image.shape)}")
        batch = image[None] if image.ndim == 3 else image
        x = as_unit(batch)
        params = self.make_params(x.shape, generator) if params is None else params
        check_params(self.effects, params)
        height, width = x.shape[-2:]
        sensor = self._sensor_index
        # The profile's chain runner, on both sides of the sensor's sampling (sRGB decoded once per run of stages).
        x = apply_effects(self.effects[:sensor], params[:sensor], x)
        x = self._resample(x, self.sensor_size(height, width))
        x = apply_effects(self.effects[sensor:], params[sensor:], x, overwrite=True)
        x = self._resample(x, (height, width))
        out = unit_to_bytes(x, overwrite=True) if batch.dtype == torch.uint8 else x.to(batch.dtype)
        return out[0] if image.ndim == 3 else out

    @staticmethod
    def _resample(x: Tensor, size: tuple[int, int]) -> Tensor:
        if tuple(x.shape[-2:]) == size:
            return x
        if size[0] < x.shape[-2] or size[1] < x.shape[-1]:
            return F.interpolate(x, size=size, mode="bilinear", antialias=True, align_corners=False)
        return F.interpolate(x, size=size, mode="bicubic", align_corners=False).clamp(0.0, 1.0)

    def describe(self) -> dict[str, Any]:
        """JSON-serialisable description: name, scale and every stage with its config and fitted values."""
        return {
            "name": self.name,
            "scale": self.scale,
            "effects": [
                {
                    "name": effect.name,
                    "stage": effect.stage,
                    "config": effect.config(),
                    "values": {key: value.tolist() for key, value in effect.state_dict().items()},
                }
                for effect in self.effects
            ],
        }

    def extra_repr(self) -> str:
        return f"name={self.name!r}, scale={self.scale}"


def _inputs(input: Path, out_dir: Path, overwrite: bool) -> list[tuple[Path, Path]]:
    """``(image, relative name)`` of every input image; a pairs folder inside the input folder is left out."""
    allow = "allow it with overwrite=True (CLI: --overwrite)"
    return input_images(input, out_dir, overwrite=overwrite, output_name="out_dir", allow=allow)


def simulate_pairs(
    preset: str | VirtualCamera,
    input: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    seed: int = 0,
    *,
    max_side: int | None = None,
    overwrite: bool = False,
) -> list[Path]:
    """Write a pairs folder made by a virtual camera: ``out_dir/clean/<name>.png`` and ``out_dir/captured/<name>.png``.

    Args:
        preset: a preset name (see :data:`PRESETS`) or a :class:`VirtualCamera`.
        input: an image file or a folder searched recursively (subfolders are mirrored).
        out_dir: the pairs folder; ``clean/`` and ``captured/`` are created in it, plus ``simulation.json``
            recording the camera and the seed.
        seed: the run seed. Each image's capture is seeded by ``seed`` and its relative path, so the same
            seed gives the same bytes whatever else is in the folder.
        max_side: downsize clean images whose longer side exceeds this (keeps demos fast).
        overwrite: allow ``out_dir`` inside the input folder (it is then left out of the inputs). No option lets an
            output replace an input image.

    Returns:
        The captured image paths, in input order (each clean image has the same relative path under ``clean/``).
        Both images of a pair have the same size (the capture's lower resolution is simulated in place).

    Raises:
        BatchError: after every readable image was simulated, when some could not be read or written
            (``error.failed``: ``(path, reason)``; ``error.done``: the captured paths written).
    """
    check_seed(seed)
    if max_side is not None:
        check_int("max_side", max_side, minimum=1)
    camera = VirtualCamera.from_preset(preset) if isinstance(preset, str) else preset
    if not isinstance(camera, VirtualCamera):
        raise TypeError(f"preset must be a preset name or a VirtualCamera, got {type(preset).__name__}")
    root = Path(out_dir)
    names: dict[Path, Path] = {}
    for path, relative in _inputs(Path(input), root, overwrite):
        name = relative.with_suffix(".png")
        if name in names:
            raise ValueError(f"inputs {str(names[name])!r} and {str(path)!r} would both be written as {str(name)!r}")
        names[name] = path
    check_outputs_spare_inputs(
        [(path, root / side / name) for name, path in names.items() for side in ("clean", "captured")]
    )
    written: list[Path] = []
    failed: list[tuple[Path, str]] = []
    for name, path in names.items():
        try:
            clean = shrink_to_max_side(read_image(path), max_side)
        except OSError as error:  # unreadable, truncated, too large, animated: reported at the end
            failed.append((path, str(error)))
            continue
        # Seeded by the relative path: the same bytes whatever else is in the folder and in whichever order.
        captured = camera(clean, generator=derived_generator(seed, "simulate", name.as_posix()))
        try:
            write_image(clean, root / "clean" / name)
            write_image(captured, root / "captured" / name)
        except OSError as error:
            failed.append((path, str(error)))
            continue
        written.append(root / "captured" / name)
    record = {"preset": camera.name, "seed": seed, "max_side": max_side, "camera": camera.describe()}
    record["skipped"] = [{"path": str(path), "reason": reason} for path, reason in failed]
    with atomic_path(root / "simulation.json") as temporary:
        temporary.write_text(json.dumps(record, indent=2, sort_keys=True) + "\n")
    if failed:
        raise BatchError(
            f"{len(failed)} of {len(names)} image(s) could not be simulated: {_listed(failed)}", failed, written
        )
    return written


def _listed(failed: Sequence[tuple[Path, str]], most: int = 5) -> str:
    shown = ", ".join(str(path) for path, _ in failed[:most])
    return shown + (f" and {len(failed) - most} more" if len(failed) > most else "")
