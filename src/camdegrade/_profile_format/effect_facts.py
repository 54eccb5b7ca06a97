"""What a profile file holds for each built-in effect, read without torch: the effect's stage, its config keys (JSON
type, default, range), its tensors (shape from the config, range) and the rules between its values.

:mod:`camdegrade._profile_format.check` checks every profile file against this table before ``camdegrade info`` shows it
or :func:`~camdegrade.load_profile` builds it. The effect classes stay the source of truth (their constructors,
``config()`` and ``check_values()``): ``tests/test_profile_validation.py`` holds this table to them, every effect,
every key, every range, so that a file one of them refuses the other refuses too.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np  # imported where values are checked: `camdegrade list` reads none

#: How JSON names the type of a value, for messages (``got a string 'false'``).
JSON_TYPES: dict[type, str] = {
    dict: "an object",
    list: "a list",
    str: "a string",
    int: "a number",
    float: "a number",
    bool: "a boolean",
    type(None): "null",
}


def short_repr(value: Any) -> str:
    """``repr(value)`` shortened to 80 characters (an integer too long for that named by its size): a file's
    metadata is quoted in messages, and its size is the file's to choose."""
    if isinstance(value, int) and value.bit_length() > 256:  # also beyond what repr converts (4300 digits)
        return f"an integer of {value.bit_length()} bits"
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def json_value(value: Any) -> str:
    """``value`` as a message names it: its JSON type, then its value shortened to 80 characters (``null``)."""
    kind = JSON_TYPES.get(type(value), type(value).__name__)
    return kind if value is None else f"{kind} {short_repr(value)}"


def shown(values: np.ndarray) -> str:
    """An array's values as ``Effect.check_values`` shows them: a number, or a short list."""
    flat = values.reshape(-1).tolist()
    if values.ndim == 0:
        return f"{flat[0]:.6g}"
    items = [round(value, 6) for value in flat[:9]]
    return f"{items}" if len(flat) <= 9 else f"{items[:-1]} ... ({len(flat)} values)"


def _number(value: int | float) -> str:
    """A config number for a message (an integer too long to print whole is named by its size)."""
    huge = isinstance(value, int) and value.bit_length() > 64
    return f"an integer of {value.bit_length()} bits" if huge else repr(value)


@dataclass(frozen=True)
class Bound:
    """Valid values: from ``low`` to ``high`` (``low`` itself excluded with ``low_open``), whole numbers only with
    ``integer``."""

    low: float
    high: float
    low_open: bool = False
    integer: bool = False

    def holds(self, values: np.ndarray | float) -> bool:
        if isinstance(values, (int, float)):  # a config value (a JSON integer may be too large for a float)
            whole = isinstance(values, int) or (math.isfinite(values) and values == round(values))
            finite = isinstance(values, int) or math.isfinite(values)
            above = self.low < values if self.low_open else self.low <= values
            return finite and above and values <= self.high and (whole or not self.integer)
        import numpy as np

        values = np.asarray(values, dtype=np.float64)
        below = values <= self.low if self.low_open else values < self.low
        inside = np.isfinite(values) & ~below & (values <= self.high)
        if self.integer:
            inside &= values == np.round(values)
        return bool(inside.all())

    def text(self) -> str:
        low = f"{self.low:g}{' (exclusive)' if self.low_open else ''}"
        return f"{'an integer ' if self.integer else ''}from {low} to {self.high:g}"


@dataclass(frozen=True)
class Setting:
    """One config key: its JSON type (``bool``, ``int``, ``float``: any number, or ``str``), its default and its
    range (its choices)."""

    kind: type
    default: Any
    bound: Bound | None = None
    #: For a ``str`` setting: the values it may take.
    choices: tuple[str, ...] = ()

    def check(self, key: str, value: Any) -> None:
        """Raise ``TypeError`` for a value of another JSON type, ``ValueError`` for one out of range (a ``str``
        setting: ``ValueError`` for anything but one of its choices)."""
        if self.kind is str:
            if not isinstance(value, str) or value not in self.choices:
                raise ValueError(f"{key} must be one of {self.choices}, got {key}={short_repr(value)}")
            return
        if self.kind is bool:
            if not isinstance(value, bool):
                raise TypeError(f"config {key!r} must be true or false, got {json_value(value)}")
            return
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            kind = "an integer" if self.kind is int else "a number"
            bound = f" {self.bound.text()}" if self.bound else ""
            raise TypeError(f"config {key!r} must be {kind}{bound}, got {json_value(value)}")
        in_range = self.bound.holds(value) if self.bound else isinstance(value, int) or math.isfinite(value)
        if (self.kind is int and not isinstance(value, int)) or not in_range:
            kind = "an integer " if self.kind is int else ""
            expected = self.bound.text() if self.bound else "finite"
            raise ValueError(f"{key} must be {kind}{expected}, got {key}={_number(value)}")


@dataclass(frozen=True)
class Buffer:
    """One tensor: its shape (numbers, or config keys whose value is the size), the config key that must be true
    (or non-zero) for it to exist, its range (every value finite in any case), and whether each row must have unit
    L2 norm."""

    shape: tuple[int | str, ...] = ()
    when: str | None = None
    bound: Bound | None = None
    unit_rows: bool = False

    def shape_for(self, config: Mapping[str, Any]) -> tuple[int, ...] | None:
        if self.when is not None and not config[self.when]:
            return None
        return tuple(int(config[size]) if isinstance(size, str) else size for size in self.shape)


#: A rule between values: an error message, or None when they agree.
Rule = Callable[[Mapping[str, Any]], str | None]


@dataclass(frozen=True)
class EffectFacts:
    """Everything a profile file records about one effect, and the checks of it (no torch)."""

    stage: str
    settings: Mapping[str, Setting] = field(default_factory=dict)
    buffers: Mapping[str, Buffer] = field(default_factory=dict)
    config_rules: tuple[Rule, ...] = ()
    value_rules: tuple[Rule, ...] = ()

    def check_config(self, config: Mapping[str, Any]) -> dict[str, Any]:
        """``config`` with defaults filled in; ``TypeError`` for unknown keys or a value of the wrong JSON type,
        ``ValueError`` for a value out of range."""
        unknown = sorted(set(config) - set(self.settings))
        if unknown:
            known = ", ".join(self.settings) or "none"
            raise TypeError(f"unknown config keys {short_repr(unknown)} (known: {known})")
        for key, value in config.items():
            self.settings[key].check(key, value)
        filled = {key: config.get(key, setting.default) for key, setting in self.settings.items()}
        for rule in self.config_rules:
            problem = rule(filled)
            if problem:
                raise ValueError(problem)
        return filled

    def tensor_shapes(self, config: Mapping[str, Any]) -> dict[str, tuple[int, ...]]:
        """The shape of every tensor of an effect with the (checked, filled) ``config``, by buffer name."""
        shapes = {key: buffer.shape_for(config) for key, buffer in self.buffers.items()}
        return {key: shape for key, shape in shapes.items() if shape is not None}

    def check_values(self, config: Mapping[str, Any], arrays: Mapping[str, np.ndarray]) -> None:
        """Raise ``ValueError`` naming the first value out of range: every value finite, then each range, unit rows
        and the rules between values, in the order ``Effect.check_values`` checks them."""
        import numpy as np

        for key, array in arrays.items():
            if not np.isfinite(array).all():
                raise ValueError(f"{key} must be finite, got {key}={shown(array)}")
        for key, buffer in self.buffers.items():
            if key not in arrays:
                continue
            values = arrays[key].astype(np.float64)
            if buffer.bound and not buffer.bound.holds(values):
                raise ValueError(f"{key} must be {buffer.bound.text()}, got {key}={shown(values)}")
            if buffer.unit_rows:
                norms = np.linalg.norm(values, axis=1)
                if not bool((np.abs(norms - 1.0) <= 1e-3 + 1e-5).all()):
                    raise ValueError(f"every row of {key} must have unit norm, got norms {norms.tolist()}")
        for rule in self.value_rules:
            problem = rule({**config, **arrays})
            if problem:
                raise ValueError(problem)


# --- the built-in effects -----------------------------------------------------------------------------------------


def _white_above_black(values: Mapping[str, Any]) -> str | None:
    black, white = values["black"], values["white"]
    if bool(white > black):
        return None
    return f"white must be greater than black, got black={shown(black)}, white={shown(white)}"


def _odd_taps(config: Mapping[str, Any]) -> str | None:
    taps = config["taps"]
    return None if taps == 0 or taps % 2 == 1 else f"taps must be 0 or odd, got taps={taps}"


def _weights_sum_to_one(values: Mapping[str, Any]) -> str | None:
    if "mixture_weights" not in values:
        return None
    total = float(values["mixture_weights"].astype("float64").sum())
    if abs(total - 1.0) <= 1e-4:  # JPEG.WEIGHT_SUM_TOLERANCE
        return None
    return f"mixture_weights must sum to 1, got a sum of {total:.6g}"


def _rows_non_decreasing(values: Mapping[str, Any]) -> str | None:
    codebook = values["codebook"]
    if bool((codebook[:, 1:] >= codebook[:, :-1]).all()):
        return None
    return f"codebook must be non-decreasing along each row, got codebook={shown(codebook)}"


def _scalars(bound: Bound | None, *names: str) -> dict[str, Buffer]:
    return {name: Buffer((), bound=bound) for name in names}


_UNIT = Bound(0.0, 1.0)
#: camdegrade.functional.sensor.resolution.UPSAMPLERS (this module imports no torch).
RESOLUTION_UPSAMPLERS = ("bicubic", "bilinear", "catmull_rom", "lanczos", "box", "nearest")
#: camdegrade.functional.sensor.resolution.SAMPLERS (a profile saved before it had none: ``antialiased``).
RESOLUTION_SAMPLERS = ("antialiased", "area")
_LINEAR = Setting(bool, True)
_NOISE_LEVEL = Bound(0.0, 1.0)  # Noise.MAX_LEVEL

#: The effects camdegrade registers, by registered name.
BUILT_IN: dict[str, EffectFacts] = {
    "blur": EffectFacts(
        "optics",
        {"linear": _LINEAR, "sigma_jitter": Setting(float, 0.0, Bound(0.0, 0.5))},
        {
            "sigma_x": Buffer(bound=Bound(0.0, 32.0)),
            "sigma_y": Buffer(bound=Bound(0.0, 32.0)),
            "angle": Buffer(),
            "motion_length": Buffer(bound=Bound(0.0, 128.0)),
            "motion_angle": Buffer(),
        },
    ),
    "cfa": EffectFacts(
        "sensor",
        {
            "pattern": Setting(str, "RGGB", choices=("RGGB", "GRBG", "GBRG", "BGGR")),  # functional.cfa.PATTERNS
            "demosaic": Setting(str, "bilinear", choices=("bilinear", "edge")),  # functional.cfa.DEMOSAICS
        },
        {"amount": Buffer(bound=Bound(0.0, 2.0))},  # ColorFilterArray.MAX_AMOUNT
    ),
    "chromatic_aberration": EffectFacts("optics", {}, _scalars(Bound(-0.1, 0.1), "red", "blue")),
    "color": EffectFacts(
        "isp",
        {"gain_jitter": Setting(float, 0.0, _UNIT), "linear": _LINEAR},
        {"matrix": Buffer((3, 3), bound=Bound(-16.0, 16.0))},
    ),
    "denoise": EffectFacts(
        "isp",
        {"luma": Setting(bool, True)},
        {
            "sigma": Buffer(bound=Bound(0.0, 8.0)),  # Denoise.MAX_SIGMA
            "threshold": Buffer(bound=Bound(0.0, 0.25)),  # Denoise.MAX_THRESHOLD
        },
    ),
    "distortion": EffectFacts("optics", {}, _scalars(Bound(-2.0, 2.0), "k1", "k2")),
    "jpeg": EffectFacts(
        "codec",
        {
            "quality_jitter": Setting(int, 0, Bound(0, 99)),
            "probability": Setting(float, 1.0, _UNIT),
            "mixture": Setting(int, 0, Bound(0, 100)),  # JPEG.MAX_MIXTURE
        },
        {
            "quality": Buffer(bound=Bound(1, 100, integer=True)),
            "mixture_qualities": Buffer(("mixture",), when="mixture", bound=Bound(1, 100, integer=True)),
            "mixture_weights": Buffer(("mixture",), when="mixture", bound=_UNIT),
        },
        value_rules=(_weights_sum_to_one,),
    ),
    "learned_texture": EffectFacts(
        "codec",
        {  # LearnedTexture: MAX_WIDTH, MAX_SIGMA
            "width": Setting(int, 8, Bound(1, 64, integer=True)),
            "noise": Setting(bool, True),
            "sigma": Setting(float, 1.5, Bound(0.0, 8.0)),
        },
        {
            key: Buffer(shape, bound=Bound(-64.0, 64.0))  # LearnedTexture.MAX_WEIGHT
            for key, shape in (
                ("conv1_weight", ("width", 4, 3, 3)),
                ("conv1_bias", ("width",)),
                ("conv2_weight", ("width", "width", 3, 3)),
                ("conv2_bias", ("width",)),
                ("conv3_weight", (3, "width", 3, 3)),
                ("conv3_bias", (3,)),
            )
        },
    ),
    "misalignment": EffectFacts(
        "optics",
        {"shift_std": Setting(float, 0.0, Bound(0.0, 64.0)), "angle_std": Setting(float, 0.0, Bound(0.0, 45.0))},
        {**_scalars(Bound(-4096.0, 4096.0), "dx", "dy"), "angle": Buffer(bound=Bound(-360.0, 360.0))},
    ),
    "frequency_response": EffectFacts(
        "isp",
        {"knots": Setting(int, 11, Bound(2, 64, integer=True))},  # FrequencyResponse: DEFAULT_KNOTS, MAX_KNOTS
        {"gains": Buffer(("knots", "knots"), bound=Bound(0.0, 8.0))},  # FrequencyResponse.MAX_GAIN
    ),
    "quantization": EffectFacts(
        "isp",
        {"levels": Setting(int, 256, Bound(2, 256, integer=True))},  # Quantization.MAX_LEVELS
        {"codebook": Buffer((3, "levels"), bound=_UNIT), "scale": Buffer(bound=Bound(0.125, 1.0))},
        value_rules=(_rows_non_decreasing,),
    ),
    "resolution": EffectFacts(
        "isp",
        {
            "upsample": Setting(str, "bicubic", choices=RESOLUTION_UPSAMPLERS),
            "sample": Setting(str, "antialiased", choices=RESOLUTION_SAMPLERS),
        },
        {"scale": Buffer(bound=Bound(0.125, 1.0))},  # Resolution.MIN_SCALE
    ),
    "noise": EffectFacts(
        "sensor",
        {
            "linear": _LINEAR,
            "gain_jitter": Setting(float, 0.0, Bound(0.0, 2.0)),
            "knots": Setting(int, 0, Bound(0, 64)),
            "taps": Setting(int, 0, Bound(0, 31)),
            "columns": Setting(bool, False),
            "mixing": Setting(bool, False),
        },
        {
            "a": Buffer((3,), bound=_NOISE_LEVEL),
            "b": Buffer((3,), bound=_NOISE_LEVEL),
            "row_sigma": Buffer((3,), bound=_NOISE_LEVEL),
            "column_sigma": Buffer((3,), when="columns", bound=_NOISE_LEVEL),
            "levels": Buffer((3, "knots"), when="knots", bound=_NOISE_LEVEL),
            "across": Buffer((3, "taps"), when="taps", unit_rows=True),
            "down": Buffer((3, "taps"), when="taps", unit_rows=True),
            "mixing": Buffer((3, 3), when="mixing", unit_rows=True),
        },
        config_rules=(_odd_taps,),
    ),
    "sharpen": EffectFacts(
        "isp",
        {"luma": Setting(bool, True)},
        {
            "sigma": Buffer(bound=Bound(0.0, 8.0)),  # Sharpen.MAX_SIGMA
            "amount": Buffer(bound=Bound(0.0, 8.0)),  # Sharpen.MAX_AMOUNT
            "threshold": Buffer(bound=Bound(0.0, 0.25)),  # Sharpen.MAX_THRESHOLD
        },
    ),
    "tone": EffectFacts(
        "isp",
        {"exposure_jitter": Setting(float, 0.0, Bound(0.0, 4.0)), "base_sigma": Setting(float, 0.0, Bound(0.0, 64.0))},
        {
            "gamma": Buffer(bound=Bound(0.0, 16.0, low_open=True)),
            **_scalars(Bound(-16.0, 16.0), "black", "white", "exposure"),
        },
        value_rules=(_white_above_black,),
    ),
    "vignetting": EffectFacts("optics", {}, _scalars(Bound(-10.0, 10.0), "k1", "k2")),
    "jitter": EffectFacts(
        "optics",
        {},
        {  # Jitter.MAX_SIGMA, Jitter.MAX_SCALE
            "sigma": Buffer(bound=Bound(0.0, 1.5)),
            "scale": Buffer(bound=Bound(1.0, 64.0)),
        },
    ),
}
