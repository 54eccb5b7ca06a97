"""Profile files read without torch: the safetensors header, the profile's metadata, a few small tensors.

``camdegrade list`` and ``camdegrade info`` answer from here in a fraction of a second (importing torch takes
seconds). :mod:`camdegrade.profile` loads every profile through the same checks (what kind of file it is, the
metadata's format, version and structure) before it builds anything; the checks that need the built modules (tensor
shapes, value ranges) stay there. Nothing here imports torch; numpy is imported only to read small tensors.

A profile file is safetensors: 8 bytes (little-endian header length), a JSON header naming every tensor's dtype,
shape and byte range, with ``__metadata__`` holding one key, :data:`METADATA_KEY`, whose value is the profile's JSON
metadata (see :meth:`camdegrade.profile.CameraProfile.metadata`).
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from camdegrade._version import __version__
from camdegrade.errors import ProfileError, UnknownProfileError

#: Value of the ``format`` metadata key in every profile file.
FORMAT_NAME = "camdegrade-profile"
#: Highest profile format version this release reads (and the one it writes).
FORMAT_VERSION = 1
#: The single safetensors metadata key holding the profile's JSON metadata.
METADATA_KEY = "camdegrade"
#: The longest JSON header read (safetensors' own limit): the header alone never makes camdegrade read more.
MAX_HEADER_BYTES = 100 * 1024 * 1024
#: The longest effect chain a profile may declare (a camera has nine kinds of stage; a few may repeat). Effects are
#: built from the metadata before the tensors are compared, so this bounds what a file can make camdegrade build.
MAX_EFFECTS = 64
#: The widest network a profile may declare (``camdegrade.network.MAX_WIDTH``, which imports torch; a test keeps
#: the two equal) and the width of a network whose config names none.
MAX_NETWORK_WIDTH = 1024
DEFAULT_NETWORK_WIDTH = 64
#: Tensors of at most this many values are shown by ``camdegrade info`` (as ``Effect.extra_repr`` does).
SHOWN_VALUES = 9

PICKLE_SUFFIXES = frozenset({".pth", ".pt", ".ckpt", ".bin", ".pkl", ".pickle", ".tar"})
_NUMPY_DTYPES = frozenset({"F64", "F32", "F16", "I64", "I32", "I16", "I8", "U64", "U32", "U16", "U8", "BOOL"})


# --- where profiles are ------------------------------------------------------------------------------------------


def builtin_profiles_dir() -> Path:
    return Path(str(resources.files("camdegrade") / "profiles"))


def list_profiles() -> list[str]:
    """Names of the profiles shipped inside the package, loadable with :func:`~camdegrade.load_profile`."""
    return sorted(path.stem for path in builtin_profiles_dir().glob("*.safetensors"))


def resolve_profile_path(name_or_path: str | os.PathLike[str]) -> Path:
    """The file a profile name or path refers to: an existing path wins over a built-in name."""
    path = Path(name_or_path)
    if path.is_file():
        return path
    if isinstance(name_or_path, str) and "/" not in name_or_path and name_or_path in list_profiles():
        return builtin_profiles_dir() / f"{name_or_path}.safetensors"
    if path.is_dir():
        raise ProfileError(f"profile {str(path)!r} is a folder, not a profile file")
    if path.exists():  # never opened: a FIFO would block the reader, a device would never end
        raise ProfileError(f"profile {str(path)!r} is not a regular file (a device, FIFO or socket)")
    blocker = next((ancestor for ancestor in path.parents if ancestor.exists()), None)
    if blocker is not None and not blocker.is_dir():
        raise ProfileError(f"profile {str(path)!r} cannot exist: {str(blocker)!r} is a file, not a folder")
    known = ", ".join(list_profiles()) or "none"
    raise UnknownProfileError(
        f"profile {str(name_or_path)!r} is neither an existing file nor a built-in profile; built-in profiles: {known}"
    )


# --- the file and its metadata ------------------------------------------------------------------------------------


def refuse_non_safetensors(path: Path) -> None:
    """Refuse anything but a safetensors file, and name pickled checkpoints as such; never unpickle."""
    try:
        with path.open("rb") as handle:
            head = handle.read(9)
        size = path.stat().st_size
    except OSError as error:  # no permission, an I/O error: a ProfileError naming the file, like the rest
        raise ProfileError(f"cannot read profile {str(path)!r}: {error.strerror or error}") from None
    header_length = int.from_bytes(head[:8], "little") if len(head) == 9 else -1
    looks_like_safetensors = 0 < header_length <= min(size - 8, MAX_HEADER_BYTES) and head[8:9] == b"{"
    if looks_like_safetensors and path.suffix.lower() not in PICKLE_SUFFIXES:
        return
    pickled = head[:2] in (b"\x80\x02", b"\x80\x03", b"\x80\x04", b"\x80\x05") or head[:4] == b"PK\x03\x04"
    if pickled or path.suffix.lower() in PICKLE_SUFFIXES:
        raise ProfileError(
            f"profile {str(path)!r} looks like a pickled PyTorch checkpoint; camdegrade only loads .safetensors "
            "profiles and never unpickles files (use camdegrade.CameraProfile(...).save('profile.safetensors'))"
        )
    raise ProfileError(f"profile {str(path)!r} is not a safetensors file (bad or truncated header)")


def serialize_metadata(metadata: Mapping[str, Any]) -> dict[str, str]:
    """The safetensors metadata for a profile: one key, canonical JSON (sorted keys), so bytes are reproducible."""
    return {METADATA_KEY: json.dumps(metadata, sort_keys=True, separators=(",", ":"))}


def parse_metadata(raw: Mapping[str, str], path: Path) -> dict[str, Any]:
    """The profile's metadata from a file's safetensors metadata ``raw``: a camdegrade profile of a format version
    this release reads, else a :class:`ProfileError`."""
    if METADATA_KEY not in raw:
        raise ProfileError(
            f"{str(path)!r} is a safetensors file but not a camdegrade profile (no {METADATA_KEY!r} metadata; "
            f"found keys: {sorted(raw) or 'none'})"
        )
    metadata = _json(raw[METADATA_KEY], f"profile {str(path)!r} has invalid JSON metadata", "JSON metadata", path)
    if not isinstance(metadata, dict) or metadata.get("format") != FORMAT_NAME:
        raise ProfileError(f"{str(path)!r} is not a camdegrade profile (metadata 'format' is not {FORMAT_NAME!r})")
    version = metadata.get("format_version")
    if isinstance(version, bool) or not isinstance(version, int):
        raise ProfileError(f"profile {str(path)!r} has format_version {version!r}, expected an integer")
    if version < 1:
        raise ProfileError(
            f"profile {str(path)!r} has format_version {version}, expected an integer from 1 to {FORMAT_VERSION}"
        )
    if version > FORMAT_VERSION:
        raise ProfileError(
            f"profile {str(path)!r} has format version {version}, newer than this camdegrade ({__version__}) reads "
            f"(up to {FORMAT_VERSION}); upgrade camdegrade"
        )
    _check_field_types(metadata, path)
    return metadata


#: Metadata entries and the JSON type each must have when present (``fitted`` and ``quality`` may also be null).
_FIELD_TYPES = {
    "name": (str, "a string"),
    "description": (str, "a string"),
    "package_version": (str, "a string"),
    "fitted": ((dict, type(None)), "an object"),
    "quality": ((dict, type(None)), "an object"),
    "effects": (list, "a list of {'name', 'config'} entries"),
}


def _check_field_types(metadata: Mapping[str, Any], path: Path) -> None:
    """Refuse metadata entries of the wrong JSON type, which would otherwise be turned into something else silently
    (a name ``["a"]`` into the text ``"['a']"``) or fail later with a message naming neither entry nor file."""
    for key, (types, expected) in _FIELD_TYPES.items():
        if key in metadata and not isinstance(metadata[key], types):
            value = metadata[key]
            shown = repr(value) if len(repr(value)) <= 80 else repr(value)[:77] + "..."
            kind = _JSON_TYPES.get(type(value), type(value).__name__)
            got = kind if value is None else f"{kind} {shown}"
            raise ProfileError(f"profile {str(path)!r} has invalid metadata: {key!r} must be {expected}, got {got}")


_JSON_TYPES: dict[type, str] = {
    dict: "an object",
    list: "a list",
    str: "a string",
    int: "a number",
    float: "a number",
    bool: "a boolean",
    type(None): "null",
}


def _json(text: str | bytes, invalid: str, part: str, path: Path) -> Any:
    """``text`` parsed; a :class:`ProfileError` starting with ``invalid`` when it is not JSON, naming ``part`` when
    it is nested too deeply to parse."""
    try:
        return json.loads(text)
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise ProfileError(f"{invalid}: {error}") from None
    except RecursionError:
        raise ProfileError(f"profile {str(path)!r} has {part} nested too deeply to read") from None


def effect_specs(metadata: Mapping[str, Any], path: Path) -> Any:
    """The metadata's ``effects`` entry (``[]`` when absent), refused when it declares more than
    :data:`MAX_EFFECTS` stages."""
    specs = metadata.get("effects", [])
    if isinstance(specs, list) and len(specs) > MAX_EFFECTS:
        raise ProfileError(
            f"profile {str(path)!r} declares {len(specs)} effect stages, more than camdegrade builds ({MAX_EFFECTS})"
        )
    return specs


def network_config(spec: Any, path: Path) -> Any:
    """The constructor arguments of the network a (non-null) ``network`` metadata entry declares."""
    if not isinstance(spec, dict) or spec.get("arch") != "DomainShiftNet":
        raise ProfileError(
            f"profile {str(path)!r} metadata 'network' must be null or {{'arch': 'DomainShiftNet', 'config': ...}}, "
            f"got {spec!r}"
        )
    return spec.get("config", {})


def effect_name(spec: Any, path: Path, known: Collection[str]) -> str:
    """The registered effect name of one ``effects`` metadata entry; ``known``: the registered names."""
    if not isinstance(spec, dict) or not isinstance(spec.get("config", {}), dict):
        raise ProfileError(f"profile {str(path)!r} has an effect entry that is not {{'name', 'config'}}: {spec!r}")
    if spec.get("name") not in known:
        raise ProfileError(
            f"profile {str(path)!r} uses effect {spec.get('name')!r}, unknown to camdegrade {__version__} "
            f"(known: {', '.join(sorted(known))}); upgrade camdegrade"
        )
    return spec["name"]


# --- the header alone ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TensorEntry:
    """One tensor as the header describes it: safetensors dtype code (``F32``) and shape."""

    dtype: str
    shape: tuple[int, ...]

    @property
    def numel(self) -> int:
        return math.prod(self.shape)


@dataclass(frozen=True)
class ProfileHeader:
    """What a profile file says about itself before any tensor is read."""

    path: Path
    metadata: dict[str, Any]
    tensors: dict[str, TensorEntry]

    @property
    def name(self) -> str:
        return str(self.metadata.get("name", ""))

    @property
    def description(self) -> str:
        return str(self.metadata.get("description", ""))

    def describe(self) -> str:
        """What ``camdegrade info`` prints: what :meth:`CameraProfile.describe` shows (name, network, effect chain
        with stages, configs and small fitted values, fitting record, quality), then the torch and torchvision
        versions the profile was fitted with and those running here. Reads the small tensors, nothing else."""
        metadata = self.metadata
        spec = metadata.get("network")
        network = "none" if spec is None else f"DomainShiftNet({network_config(spec, self.path)})"
        lines = [
            f"name:        {self.name or '(unnamed)'}",
            f"description: {self.description or '-'}",
            f"network:     {network}",
        ]
        lines += self._effect_lines()
        lines.append(f"fitted:      {json.dumps(metadata.get('fitted') or {}, sort_keys=True)}")
        lines.append(f"quality:     {json.dumps(metadata.get('quality') or {}, sort_keys=True)}")
        lines.append(f"written by:  camdegrade {metadata.get('package_version', 'unknown')}")
        lines.append(f"fitted with: {_versions(self.recorded_versions())}")
        lines.append(f"running:     {_versions(running_versions())}")
        return "\n".join(lines)

    def _effect_lines(self) -> list[str]:
        specs = self.metadata.get("effects") or []
        stages = effect_stages(specs)
        buffers = sorted(key for key in self.tensors if key.startswith("effects.") and key.count(".") == 2)
        values = read_small_values(self, buffers)
        lines = [f"effects:     {len(specs)}"]
        for index, spec in enumerate(specs):
            items = [f"{key}={value!r}" for key, value in spec.get("config", {}).items()]
            for key in (key for key in buffers if key.startswith(f"effects.{index}.")):
                shown = values.get(key, f"<{'x'.join(str(size) for size in self.tensors[key].shape)}>")
                items.append(f"{key.rsplit('.', 1)[1]}={shown}")
            lines.append(f"  {index}. {spec['name']} [{stages[spec['name']]}] {', '.join(items)}")
        if len(values) < len(buffers):
            lines.append(f"  (<AxB>: the shape of a tensor of more than {SHOWN_VALUES} values, not shown)")
        return lines

    def recorded_versions(self) -> dict[str, str | None]:
        """The torch and torchvision versions the profile was fitted with (``None``: not recorded). ``fit_profile``
        records both in ``fitted``; older profiles name torch only, in ``fitted['machine']``."""
        fitted = self.metadata.get("fitted")
        fitted = fitted if isinstance(fitted, dict) else {}
        versions = {package: fitted.get(package) for package in _PACKAGES}
        machine = fitted.get("machine")
        if versions["torch"] is None and isinstance(machine, str):
            found = re.search(r"\btorch\s+(\d[^\s,;]*)", machine)
            versions["torch"] = found.group(1) if found else None
        return {package: value if isinstance(value, str) and value else None for package, value in versions.items()}

    def version_warnings(self, running: Mapping[str, str | None] | None = None) -> list[str]:
        """One line per package whose running version (default: :func:`running_versions`) is another major release
        (the first number of the version) than the one the profile was fitted with."""
        running = running_versions() if running is None else running
        warnings = []
        for package, fitted in self.recorded_versions().items():
            here = running.get(package)
            if fitted and here and None not in (_major(fitted), _major(here)) and _major(fitted) != _major(here):
                warnings.append(
                    f"profile {self.name or str(self.path)!r} was fitted with {package} {fitted} and this is {package} "
                    f"{here}, another major release: its outputs may differ from the quality it records"
                )
        return warnings


def read_header(name_or_path: str | os.PathLike[str]) -> ProfileHeader:
    """A built-in profile's or a profile file's header and metadata, checked as :func:`~camdegrade.load_profile`
    checks them before building anything (file kind, header size, format, version, network and effect entries,
    effect names); tensor values are not read. Anything wrong is a one-line :class:`ProfileError`.

    Examples:
        >>> read_header("city100-iphonex").metadata["network"]
        {'arch': 'DomainShiftNet', 'config': {'width': 64}}
    """
    path = resolve_profile_path(name_or_path)
    refuse_non_safetensors(path)
    corrupt = f"profile file {str(path)!r} is corrupt or truncated"
    with path.open("rb") as handle:
        length = int.from_bytes(handle.read(8), "little")  # bounded by refuse_non_safetensors
        header = _json(handle.read(length), f"{corrupt} (its header is not JSON)", "a header", path)
    raw = (header.pop("__metadata__", None) or {}) if isinstance(header, dict) else None
    if not isinstance(raw, dict) or not all(isinstance(value, str) for value in raw.values()):
        raise ProfileError(f"{corrupt} (not a safetensors header); fit or copy it again")
    metadata = parse_metadata(raw, path)
    try:
        tensors = {
            key: TensorEntry(str(entry["dtype"]), tuple(int(size) for size in entry["shape"]))
            for key, entry in header.items()
        }
        data_end = max((int(entry["data_offsets"][1]) for entry in header.values()), default=0)
    except (TypeError, KeyError, ValueError, IndexError):
        raise ProfileError(
            f"{corrupt} (a tensor entry lacks its dtype or shape, or its data offsets); fit or copy it again"
        ) from None
    size = path.stat().st_size
    if size != 8 + length + data_end:  # load_profile refuses such a file too (safetensors checks the same)
        found = "is cut short" if size < 8 + length + data_end else "has bytes after its data"
        raise ProfileError(
            f"{corrupt} (its header places {data_end} bytes of tensor data after it, but the file {found}: "
            f"{size} bytes, expected {8 + length + data_end}); fit or copy it again"
        )
    _check_structure(metadata, path)
    return ProfileHeader(path, metadata, tensors)


def _check_structure(metadata: Mapping[str, Any], path: Path) -> None:
    """The network and effect entries, as :func:`~camdegrade.load_profile` checks them while building."""
    specs = effect_specs(metadata, path)
    try:
        spec = metadata.get("network")
        if spec is not None:
            check_network_config(network_config(spec, path))
        specs = list(specs)
        stages = effect_stages(specs)
        for spec in specs:
            effect_name(spec, path, stages)
    except (TypeError, ValueError, AttributeError, KeyError) as error:
        if isinstance(error, ProfileError):
            raise
        raise ProfileError(f"profile {str(path)!r} has invalid metadata: {error}") from error


def check_network_config(config: Any) -> None:
    """Raise as ``DomainShiftNet(**config)`` would for a config it refuses (a test keeps the two in step)."""
    if not isinstance(config, dict):
        raise TypeError(f"the network config must be a mapping, got {type(config).__name__}")
    unexpected = sorted(set(config) - {"width"})
    if unexpected:
        raise TypeError(f"unexpected network config keys {unexpected}")
    width = config.get("width", DEFAULT_NETWORK_WIDTH)
    if isinstance(width, bool) or not isinstance(width, int) or not 1 <= width <= MAX_NETWORK_WIDTH:
        raise ValueError(f"width must be an integer from 1 to {MAX_NETWORK_WIDTH}, got width={width!r}")


def read_small_values(header: ProfileHeader, keys: Sequence[str]) -> dict[str, Any]:
    """The values of those of the tensors ``keys`` that hold at most :data:`SHOWN_VALUES` values of a dtype numpy
    reads, read with safetensors' numpy loader (no torch): a number for a 0-d tensor, else a flat list, floats
    rounded to 6 decimals (as :meth:`Effect.extra_repr` shows them)."""
    wanted = [
        key for key in keys if header.tensors[key].numel <= SHOWN_VALUES and header.tensors[key].dtype in _NUMPY_DTYPES
    ]
    if not wanted:
        return {}
    from safetensors import SafetensorError, safe_open

    try:
        with safe_open(str(header.path), framework="numpy") as handle:
            arrays = {key: handle.get_tensor(key) for key in wanted}
    except (SafetensorError, OSError) as error:
        raise ProfileError(
            f"profile file {str(header.path)!r} is corrupt or truncated ({error}); fit or copy it again"
        ) from None
    shown = {}
    for key, array in arrays.items():
        items = [round(value, 6) if isinstance(value, float) else value for value in array.reshape(-1).tolist()]
        shown[key] = items[0] if array.ndim == 0 else items
    return shown


# --- versions -----------------------------------------------------------------------------------------------------

_PACKAGES = ("torch", "torchvision")


def running_versions() -> dict[str, str | None]:
    """The installed torch and torchvision versions (``None``: not installed), read without importing them."""
    import importlib.metadata  # about 0.1 s: only when asked

    versions: dict[str, str | None] = {}
    for package in _PACKAGES:
        try:
            versions[package] = importlib.metadata.version(package)
        except importlib.metadata.PackageNotFoundError:
            versions[package] = None
    return versions


def _versions(versions: Mapping[str, str | None]) -> str:
    return ", ".join(f"{package} {version or '(not recorded)'}" for package, version in versions.items())


def _major(version: str) -> int | None:
    found = re.match(r"\s*v?(\d+)", version)
    return int(found.group(1)) if found else None


# --- effect stages, without importing the effects -----------------------------------------------------------------


def effect_stages(specs: Sequence[object] = ()) -> dict[str, str]:
    """``{name: stage}`` for the effect entries ``specs`` of a profile's metadata.

    Profiles record each stage's ``stage`` beside its name (written since format version 1 gained the key), so
    ``info`` shows them without importing the effects (they import torch). For an entry without it (an older
    profile), the registry (:data:`camdegrade.effects.EFFECTS`) is asked after all, which also refuses unknown names.
    """
    entries = [spec for spec in specs if isinstance(spec, dict)]
    recorded = {spec.get("name"): spec.get("stage") for spec in entries}
    if entries and all(isinstance(name, str) and isinstance(stage, str) for name, stage in recorded.items()):
        return recorded  # type: ignore[return-value]
    from camdegrade.effects import EFFECTS

    return {name: cls.stage for name, cls in EFFECTS.items()}
