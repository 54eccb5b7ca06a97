"""The one check of a profile file, without torch: whatever :func:`~camdegrade.load_profile` refuses,
``camdegrade info`` refuses too, with the same one-line :class:`~camdegrade.errors.ProfileError`.

:func:`check_profile` takes what :func:`~camdegrade._profile_format.header.read_header` read (the metadata and the
header's tensor entries) and checks, in order: the network entry (architecture, width), every effect entry (a known
effect, its recorded stage, its config keys, their JSON types and ranges), the byte layout of the tensors (each
dtype's size times its shape, no gaps or overlaps), the tensors against what the metadata declares (names, shapes,
float dtypes; nothing missing, nothing extra). :func:`check_values` then reads the tensors with safetensors' numpy
loader and checks the values (network weights finite, every effect value in its range); ``camdegrade info`` and
``load_profile`` run both, ``camdegrade list`` (which shows no value) the first.

Built-in effects are checked against :data:`~camdegrade._profile_format.effect_facts.BUILT_IN`; an effect registered
by other code (a plugin, a test) is asked of its class, which is only possible where the registry has been imported
(and torch with it): a ``camdegrade info`` process has neither, and knows only the built-ins.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from camdegrade._profile_format.effect_facts import BUILT_IN, json_value, short_repr
from camdegrade._profile_format.network_entry import network_shapes_of
from camdegrade._version import __version__
from camdegrade.errors import ProfileError, ProfileTypeError

if TYPE_CHECKING:
    import numpy as np  # imported where values are read: `camdegrade list` reads none

#: The longest effect chain a profile may declare (a camera has nine kinds of stage; a few may repeat). Effects are
#: built from the metadata before the tensors are read, so this bounds what a file can make camdegrade build.
MAX_EFFECTS = 64
#: Bytes per value of each safetensors dtype a file may hold (the sub-byte float types never hold a profile).
DTYPE_SIZES = {"BOOL": 1, "U8": 1, "I8": 1, "F8_E5M2": 1, "F8_E4M3": 1, "I16": 2, "U16": 2, "F16": 2, "BF16": 2}
DTYPE_SIZES |= {"I32": 4, "U32": 4, "F32": 4, "I64": 8, "U64": 8, "F64": 8, "C64": 8}
#: The dtypes a profile's float tensors may have (what ``CameraProfile.save`` writes, and float64).
FLOAT_DTYPES = ("F32", "F64")
#: The entries of one effect in the metadata's ``effects`` list.
EFFECT_ENTRY_KEYS = ("name", "stage", "config")
#: Names listed per kind of mismatch in an error (the rest are counted).
LISTED = 10


@dataclass(frozen=True)
class TensorEntry:
    """One tensor as the header describes it: safetensors dtype code (``F32``), shape, and its byte range in the
    data that follows the header."""

    dtype: str
    shape: tuple[int, ...]
    offsets: tuple[int, int] = (0, 0)

    @property
    def numel(self) -> int:
        count = 1
        for size in self.shape:
            count *= size
        return count


class Facts(Protocol):
    """What the check asks of an effect (for the built-ins:
    :class:`~camdegrade._profile_format.effect_facts.EffectFacts`)."""

    stage: str

    def check_config(self, config: Mapping[str, Any]) -> dict[str, Any]: ...

    def tensor_shapes(self, config: Mapping[str, Any]) -> dict[str, tuple[int, ...]]: ...

    def check_values(self, config: Mapping[str, Any], arrays: Mapping[str, np.ndarray]) -> None: ...


@dataclass(frozen=True)
class _Stage:
    """One effect entry, checked: where it is, what it is, its config with defaults filled in."""

    index: int
    name: str
    facts: Facts
    config: dict[str, Any]

    @property
    def label(self) -> str:
        return f"effect {self.index} ({self.name})"


def check_profile(path: Path, metadata: Mapping[str, Any], tensors: Mapping[str, TensorEntry]) -> None:
    """Raise a one-line :class:`ProfileError` for anything :func:`~camdegrade.load_profile` would refuse in the
    profile at ``path``, whose parsed metadata and header entries are ``metadata`` and ``tensors``, short of the
    tensors' values (:func:`check_values`): the network and effect entries, the tensors' layout, names, shapes and
    dtypes."""
    _network, _stages, expected = _declared(path, metadata)
    check_layout(tensors, path)
    compare_tensors(expected, tensors, path)


def check_values(path: Path, metadata: Mapping[str, Any], tensors: Mapping[str, TensorEntry]) -> None:
    """Raise a one-line :class:`ProfileError` for a value out of its range in a profile :func:`check_profile`
    passed: a network weight that is not finite, an effect value outside what its effect allows."""
    import numpy as np

    network, stages, expected = _declared(path, metadata)
    arrays = read_arrays(path, [key for key in expected if tensors[key].dtype in FLOAT_DTYPES])
    for key in network:
        if not np.isfinite(arrays[key]).all():
            bad = int((~np.isfinite(arrays[key])).sum())
            raise ProfileError(f"profile {str(path)!r}: {key} must be finite, got {bad} NaN or infinite values")
    for stage in stages:
        prefix = f"effects.{stage.index}."
        values = {key[len(prefix) :]: array for key, array in arrays.items() if key.startswith(prefix)}
        try:
            stage.facts.check_values(stage.config, values)
        except ValueError as error:
            raise ProfileError(f"profile {str(path)!r}: {stage.label}: {error}") from None


def _declared(
    path: Path, metadata: Mapping[str, Any]
) -> tuple[dict[str, tuple[int, ...]], list[_Stage], dict[str, tuple[int, ...]]]:
    """The network tensors, the checked effect entries, and every tensor (name → shape) the metadata declares."""
    network = network_shapes_of(metadata.get("network"), path)
    stages = [_checked_stage(index, spec, path) for index, spec in enumerate(effect_specs(metadata, path))]
    expected = dict(network)
    for stage in stages:
        expected |= {f"effects.{stage.index}.{key}": shape for key, shape in _shapes(stage, path).items()}
    return network, stages, expected


# --- the network --------------------------------------------------------------------------------------------------


# --- the effects --------------------------------------------------------------------------------------------------


def effect_specs(metadata: Mapping[str, Any], path: Path) -> list[Any]:
    """The metadata's ``effects`` entry (``[]`` when absent), refused when it declares more than
    :data:`MAX_EFFECTS` stages."""
    specs = metadata.get("effects", [])
    if len(specs) > MAX_EFFECTS:
        raise ProfileError(
            f"profile {str(path)!r} declares {len(specs)} effect stages, more than camdegrade builds ({MAX_EFFECTS})"
        )
    return list(specs)


def effect_facts(name: str) -> Facts | None:
    """What the check knows of the effect registered as ``name``: the built-in table, else the registered class
    (only where the registry is imported already), else None."""
    if name in BUILT_IN:
        return BUILT_IN[name]
    registry = sys.modules.get("camdegrade.effects")
    cls = getattr(registry, "EFFECTS", {}).get(name) if registry is not None else None
    return _RegisteredEffect(cls) if cls is not None else None


def known_effects() -> list[str]:
    registry = sys.modules.get("camdegrade.effects")
    return sorted({*BUILT_IN, *getattr(registry, "EFFECTS", {})})


def named_effect(spec: Any, path: Path) -> tuple[str, Facts]:
    """The registered name of one ``effects`` metadata entry, and what the check knows of that effect."""
    if not isinstance(spec, dict) or not isinstance(spec.get("config", {}), dict):
        raise ProfileError(
            f"profile {str(path)!r} has an effect entry that is not {{'name', 'config'}}: {short_repr(spec)}"
        )
    name = spec.get("name")
    if not isinstance(name, str):
        raise ProfileTypeError(
            f"profile {str(path)!r} has invalid metadata: an effect's 'name' must be a string, got {json_value(name)}"
        )
    facts = effect_facts(name)
    if facts is None:
        raise ProfileError(
            f"profile {str(path)!r} uses effect {short_repr(name)}, unknown to camdegrade {__version__} "
            f"(known: {', '.join(known_effects())}); upgrade camdegrade"
        )
    return name, facts


def _checked_stage(index: int, spec: Any, path: Path) -> _Stage:
    """One effect entry: a known effect, only the keys an entry has, the stage its kind sits at, a valid config."""
    name, facts = named_effect(spec, path)
    label, invalid = f"effect {index} ({name})", f"profile {str(path)!r} has invalid metadata"
    unknown = sorted(set(spec) - set(EFFECT_ENTRY_KEYS))
    if unknown:
        raise ProfileError(
            f"{invalid}: {label} has unknown keys {short_repr(unknown)} (an entry holds 'name', 'stage', 'config')"
        )
    if "stage" in spec and spec["stage"] != facts.stage:
        raise ProfileError(
            f"{invalid}: {label} is recorded at stage {short_repr(spec['stage'])}, but {name} belongs to stage "
            f"{facts.stage!r}"
        )
    try:
        config = facts.check_config(spec.get("config", {}))
    except TypeError as error:
        raise ProfileTypeError(f"{invalid}: {label}: {error}") from None
    except ValueError as error:
        raise ProfileError(f"{invalid}: {label}: {error}") from None
    return _Stage(index, name, facts, config)


def _shapes(stage: _Stage, path: Path) -> dict[str, tuple[int, ...]]:
    try:
        return stage.facts.tensor_shapes(stage.config)
    except (TypeError, ValueError) as error:  # a registered class refusing its own config
        raise ProfileError(f"profile {str(path)!r} has invalid metadata: {stage.label}: {error}") from None


class _RegisteredEffect:
    """An effect registered by other code (a plugin, a test), checked by its class: ``from_config`` for the config
    and the tensor shapes, ``check_values`` for the values. Torch is imported already (the registry imports it)."""

    def __init__(self, cls: Any) -> None:
        self.cls = cls
        self.stage = cls.stage

    def check_config(self, config: Mapping[str, Any]) -> dict[str, Any]:
        self.cls.from_config(dict(config))
        return dict(config)

    def tensor_shapes(self, config: Mapping[str, Any]) -> dict[str, tuple[int, ...]]:
        state = self.cls.from_config(dict(config)).state_dict()
        return {key: tuple(value.shape) for key, value in state.items()}

    def check_values(self, config: Mapping[str, Any], arrays: Mapping[str, np.ndarray]) -> None:
        import torch

        effect = self.cls.from_config(dict(config))
        effect.load_state_dict({key: torch.from_numpy(value.copy()) for key, value in arrays.items()}, strict=False)
        effect.check_values()


# --- the tensors --------------------------------------------------------------------------------------------------


def tensor_entries(header: Mapping[str, Any], corrupt: str) -> dict[str, TensorEntry]:
    """The tensor entries of a safetensors header (``__metadata__`` removed); ``corrupt`` starts the message of an
    entry without a dtype, a shape of whole numbers or a byte range."""
    entries = {key: _entry(value) for key, value in header.items()}
    if None in entries.values():
        raise ProfileError(
            f"{corrupt} (a tensor entry lacks its dtype or shape, or its data offsets); fit or copy it again"
        )
    return {key: entry for key, entry in entries.items() if entry is not None}


def _entry(entry: Any) -> TensorEntry | None:
    """One header entry as a :class:`TensorEntry`, or None unless it holds a dtype name, a shape and a byte range
    of whole numbers from 0."""
    if not isinstance(entry, dict):
        return None
    dtype, shape, offsets = entry.get("dtype"), entry.get("shape"), entry.get("data_offsets")
    if not (isinstance(dtype, str) and isinstance(shape, list) and isinstance(offsets, list) and len(offsets) == 2):
        return None
    if not all(isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in (*shape, *offsets)):
        return None
    return TensorEntry(dtype, tuple(shape), (offsets[0], offsets[1]))


def check_layout(tensors: Mapping[str, TensorEntry], path: Path) -> None:
    """Refuse byte ranges that do not hold exactly their tensor (a relabelled dtype or shape), or that overlap or
    leave gaps, as safetensors refuses them."""
    corrupt = f"profile file {str(path)!r} is corrupt or truncated"
    end = 0
    for key, entry in sorted(tensors.items(), key=lambda item: item[1].offsets):
        size = DTYPE_SIZES.get(entry.dtype)
        if size is None:
            raise ProfileError(
                f"{corrupt} (tensor {short_repr(key)} has dtype {short_repr(entry.dtype)}, which no profile holds)"
            )
        start, stop = entry.offsets
        if start != end:
            raise ProfileError(
                f"{corrupt} (tensor {short_repr(key)} starts at byte {start} of the data, expected {end})"
            )
        if stop - start != entry.numel * size:
            raise ProfileError(
                f"{corrupt} (tensor {short_repr(key)} holds {stop - start} bytes, but {short_repr(entry.numel)} "
                f"values of dtype {dtype_name(entry.dtype)} take {short_repr(entry.numel * size)}); fit or copy it "
                "again"
            )
        end = stop


def compare_tensors(expected: Mapping[str, tuple[int, ...]], found: Mapping[str, TensorEntry], path: Path) -> None:
    """Compare the file's tensors with the ``expected`` float tensors' shapes; a :class:`ProfileError` lists every
    difference."""
    common = sorted(set(expected) & set(found))
    missing = sorted(set(expected) - set(found))
    unexpected = sorted(set(found) - set(expected))
    wrong_shape = [
        f"{key} {found[key].shape} (expected {expected[key]})" for key in common if found[key].shape != expected[key]
    ]
    wrong_dtype = [
        f"{key} has dtype {dtype_name(found[key].dtype)}, expected float32 or float64"
        for key in common
        if found[key].dtype not in FLOAT_DTYPES
    ]
    kinds = (
        ("missing tensors", missing),
        ("unexpected tensors", unexpected),
        ("wrong shapes", wrong_shape),
        ("wrong dtypes", wrong_dtype),
    )
    problems = [f"{kind}: {listing(items)}" for kind, items in kinds if items]
    if problems:
        raise ProfileError(f"profile {str(path)!r} does not match its own metadata; " + "; ".join(problems))


def read_arrays(path: Path, keys: Sequence[str]) -> dict[str, np.ndarray]:
    """The tensors ``keys`` of the file at ``path``, read with safetensors' numpy loader (no torch)."""
    if not keys:
        return {}
    from safetensors import SafetensorError, safe_open

    try:
        with safe_open(str(path), framework="numpy") as handle:
            return {key: handle.get_tensor(key) for key in keys}
    except (SafetensorError, OSError) as error:
        raise ProfileError(
            f"profile file {str(path)!r} is corrupt or truncated ({error}); fit or copy it again"
        ) from None


def listing(items: list[str]) -> str:
    """The first :data:`LISTED` of ``items``, each shortened to 80 characters, and how many more."""
    more = f" and {len(items) - LISTED} more" if len(items) > LISTED else ""
    return ", ".join(item if len(item) <= 80 else item[:77] + "..." for item in items[:LISTED]) + more


_DTYPE_PREFIXES = {"F": "float", "BF": "bfloat", "I": "int", "U": "uint", "C": "complex"}


def dtype_name(code: str) -> str:
    """A safetensors dtype code as torch names it: ``I32`` → ``int32``."""
    prefix = code.rstrip("0123456789")
    bits = code[len(prefix) :]
    return f"{_DTYPE_PREFIXES[prefix]}{bits}" if prefix in _DTYPE_PREFIXES and bits else code.lower()
