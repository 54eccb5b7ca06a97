"""Profile files read without torch: the safetensors header, the profile's metadata, a few small tensors.

``camdegrade list`` and ``camdegrade info`` answer from here in a fraction of a second (importing torch takes
seconds). :func:`read_header` reads a file and checks it (:mod:`camdegrade._profile_format.check`: metadata, effect
entries, tensor names, dtypes and shapes; the values when they are shown or loaded); :func:`camdegrade.load_profile`
reads every profile through it before it builds anything, so the two refuse the same files. Nothing here imports
torch; numpy reads the tensors (``camdegrade list`` reads none).

A profile file is safetensors: 8 bytes (little-endian header length), a JSON header naming every tensor's dtype,
shape and byte range, with ``__metadata__`` holding one key, :data:`METADATA_KEY`, whose value is the profile's JSON
metadata (see :meth:`camdegrade.profile.CameraProfile.metadata`).
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from camdegrade._profile_format.check import MAX_EFFECTS as MAX_EFFECTS
from camdegrade._profile_format.check import TensorEntry as TensorEntry
from camdegrade._profile_format.check import (
    check_profile,
    check_values,
    effect_facts,
    read_arrays,
    tensor_entries,
)
from camdegrade._profile_format.effect_facts import json_value, short_repr
from camdegrade._profile_format.network_entry import DEFAULT_NETWORK_WIDTH as DEFAULT_NETWORK_WIDTH
from camdegrade._profile_format.network_entry import MAX_NETWORK_WIDTH as MAX_NETWORK_WIDTH
from camdegrade._profile_format.network_entry import network_class, network_config
from camdegrade._version import __version__
from camdegrade.errors import ProfileError, ProfileTypeError, UnknownProfileError

#: Value of the ``format`` metadata key in every profile file.
FORMAT_NAME = "camdegrade-profile"
#: Highest profile format version this release reads (and the one it writes).
FORMAT_VERSION = 1
#: The single safetensors metadata key holding the profile's JSON metadata.
METADATA_KEY = "camdegrade"
#: The longest JSON header read (safetensors' own limit): the header alone never makes camdegrade read more.
MAX_HEADER_BYTES = 100 * 1024 * 1024
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
            f"found keys: {short_repr(sorted(raw)) if raw else 'none'})"
        )
    metadata = _json(raw[METADATA_KEY], f"profile {str(path)!r} has invalid JSON metadata", "JSON metadata", path)
    if not isinstance(metadata, dict) or metadata.get("format") != FORMAT_NAME:
        raise ProfileError(f"{str(path)!r} is not a camdegrade profile (metadata 'format' is not {FORMAT_NAME!r})")
    version = metadata.get("format_version")
    if isinstance(version, bool) or not isinstance(version, int):
        raise ProfileError(f"profile {str(path)!r} has format_version {short_repr(version)}, expected an integer")
    if version < 1:
        raise ProfileError(
            f"profile {str(path)!r} has format_version {short_repr(version)}, expected an integer from 1 to "
            f"{FORMAT_VERSION}"
        )
    if version > FORMAT_VERSION:
        raise ProfileError(
            f"profile {str(path)!r} has format version {short_repr(version)}, newer than this camdegrade "
            f"({__version__}) reads (up to {FORMAT_VERSION}); upgrade camdegrade"
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
            raise ProfileTypeError(
                f"profile {str(path)!r} has invalid metadata: {key!r} must be {expected}, "
                f"got {json_value(metadata[key])}"
            )


def _json(text: str | bytes, invalid: str, part: str, path: Path) -> Any:
    """``text`` parsed; a :class:`ProfileError` starting with ``invalid`` when it is not JSON, naming ``part`` when
    it is nested too deeply to parse."""
    try:
        return json.loads(text)
    except ValueError as error:  # not JSON, not UTF-8, or an integer of more digits than Python converts
        raise ProfileError(f"{invalid}: {error}") from None
    except RecursionError:
        raise ProfileError(f"profile {str(path)!r} has {part} nested too deeply to read") from None


# --- the header alone ---------------------------------------------------------------------------------------------


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

    def check_values(self) -> None:
        """Raise a one-line :class:`ProfileError` for a tensor value out of its range (a network weight that is not
        finite, an effect value its effect refuses), as :func:`~camdegrade.load_profile` refuses it. Reads every
        tensor (numpy, no torch)."""
        check_values(self.path, self.metadata, self.tensors)

    def describe(self) -> str:
        """What ``camdegrade info`` prints: what :meth:`CameraProfile.describe` shows (name, network, effect chain
        with stages, configs and small fitted values, fitting record, quality), then the torch and torchvision
        versions the profile was fitted with and those running here. The values are checked first
        (:meth:`check_values`): a file ``load_profile`` refuses is refused here too, never shown."""
        self.check_values()
        metadata = self.metadata
        spec = metadata.get("network")
        # the config's keys sorted (what older files leave out comes first from network_config), as describe() shows
        config = None if spec is None else dict(sorted(network_config(spec, self.path).items()))
        network = "none" if spec is None else f"{network_class(spec, self.path)}({config})"
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
        buffers = sorted(key for key in self.tensors if key.startswith("effects.") and key.count(".") == 2)
        values = read_small_values(self, buffers)
        lines = [f"effects:     {len(specs)}"]
        for index, spec in enumerate(specs):
            items = [f"{key}={value!r}" for key, value in spec.get("config", {}).items()]
            for key in (key for key in buffers if key.startswith(f"effects.{index}.")):
                shown = values.get(key, f"<{'x'.join(str(size) for size in self.tensors[key].shape)}>")
                items.append(f"{key.rsplit('.', 1)[1]}={shown}")
            lines.append(f"  {index}. {spec['name']} [{_stage(spec['name'])}] {', '.join(items)}")
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


def _stage(name: str) -> str:
    facts = effect_facts(name)
    return facts.stage if facts is not None else "?"  # never "?": read_header refuses unknown effects


def read_header(name_or_path: str | os.PathLike[str]) -> ProfileHeader:
    """A built-in profile's or a profile file's header and metadata, checked before anything is shown or built
    (file kind, header size, format, version, then :func:`~camdegrade._profile_format.check.check_profile`: the
    network and effect entries, the tensors' names, dtypes, shapes and byte ranges); the values are checked by
    :meth:`ProfileHeader.check_values`, which :meth:`~ProfileHeader.describe` (``camdegrade info``) and
    :func:`~camdegrade.load_profile` call. Anything wrong is a one-line :class:`ProfileError`.

    Examples:
        >>> read_header("city100-iphonex").metadata["network"]
        {'arch': 'LocalAffineNet', 'config': {'curves': True, 'upsample': 'bilinear', 'width': 64}}
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
    tensors = tensor_entries(header, corrupt)
    data_end = max((entry.offsets[1] for entry in tensors.values()), default=0)
    size = path.stat().st_size
    if size != 8 + length + data_end:  # load_profile refuses such a file too (safetensors checks the same)
        found = "is cut short" if size < 8 + length + data_end else "has bytes after its data"
        raise ProfileError(
            f"{corrupt} (its header places {data_end} bytes of tensor data after it, but the file {found}: "
            f"{size} bytes, expected {8 + length + data_end}); fit or copy it again"
        )
    check_profile(path, metadata, tensors)
    return ProfileHeader(path, metadata, tensors)


def read_small_values(header: ProfileHeader, keys: Sequence[str]) -> dict[str, Any]:
    """The values of those of the tensors ``keys`` that hold at most :data:`SHOWN_VALUES` values of a dtype numpy
    reads, read with safetensors' numpy loader (no torch): a number for a 0-d tensor, else a flat list, floats
    rounded to 6 decimals (as :meth:`Effect.extra_repr` shows them)."""
    wanted = [
        key for key in keys if header.tensors[key].numel <= SHOWN_VALUES and header.tensors[key].dtype in _NUMPY_DTYPES
    ]
    arrays = read_arrays(header.path, wanted)
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
