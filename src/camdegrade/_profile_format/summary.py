"""A profile for people: a short summary (``camdegrade info PROFILE``, ``make demo``, the end of ``camdegrade fit``)
and the full record (``camdegrade info PROFILE --json``).

The summary is one line per stage of the chain with its key values, the network (architecture, width, parameters),
the recorded quality (PSNR from the clean image to the profile, fidelity, the critics) and the warnings, each line at
most :data:`WIDTH` characters. Both read the file's header and its effect tensors (safetensors' numpy loader): no
torch. Names and descriptions come from files, so they are shown escaped (:func:`~camdegrade._support.text.printable`).

Examples:
    >>> print(profile_summary("city100-iphonex").splitlines()[0])
    profile    city100-iphonex
"""

from __future__ import annotations

import os
import textwrap
from collections.abc import Mapping
from typing import Any

from camdegrade._profile_format import header as _header
from camdegrade._profile_format.check import effect_facts, read_arrays
from camdegrade._profile_format.header import ProfileHeader, read_header
from camdegrade._support.text import printable

__all__ = ["WIDTH", "profile_record", "profile_summary", "quality_lines"]

#: The widest line of a summary (characters).
WIDTH = 120
#: The label column (``network``, ``held-out``, ...) and the indent of continued lines.
_LABEL = 11
#: A stage's vectors of at most this many values are shown; larger tensors by their shape.
_SHOWN = 3


def profile_summary(profile: str | os.PathLike[str]) -> str:
    """The summary of a built-in profile name or a ``.safetensors`` file, checked as :func:`~camdegrade.load_profile`
    checks it (a file it refuses is refused here too, with the same one-line :class:`~camdegrade.ProfileError`)."""
    header = read_header(profile)
    header.check_values()
    metadata, fitted = header.metadata, _mapping(header.metadata.get("fitted"))
    lines = _labelled("profile", printable(header.name or "(unnamed)"))
    if header.description:
        lines += _labelled("", printable(header.description), most=2)
    lines += _labelled("network", _network(header))
    lines += _chain(header)
    lines += _fit(fitted)
    lines += quality_lines(_mapping(metadata.get("quality")))
    warnings = [printable(warning) for warning in fitted.get("warnings") or []]
    lines += _labelled("warnings", "; ".join(warnings) or "none", most=3)
    versions = f"fitted with {_versions(header.recorded_versions())}; running {_versions(_header.running_versions())}"
    return "\n".join(lines + _labelled("versions", versions))


def profile_record(profile: str | os.PathLike[str]) -> dict[str, Any]:
    """Everything the file says about itself, for ``--json``: its metadata as stored (name, description, network,
    effects, ``fitted``, ``quality``, ...), plus ``values`` (every effect tensor, floats rounded to 6 decimals; the
    network's weights are left out) and ``versions`` (the torch and torchvision it was fitted with and those here)."""
    header = read_header(profile)
    header.check_values()
    keys = [key for key in header.tensors if key.startswith("effects.")]
    values = {key: _rounded(array.tolist()) for key, array in read_arrays(header.path, keys).items()}
    versions = {"fitted_with": header.recorded_versions(), "running": _header.running_versions()}
    return {**header.metadata, "values": values, "versions": versions}


def quality_lines(quality: Mapping[str, Any]) -> list[str]:
    """The lines for a profile's ``quality`` record: PSNR, fidelity and critics of each record it holds (held-out
    pairs, validation pairs, an unpaired fit's set statistics, a distilled network against its teacher)."""
    lines = _record(quality)
    nested = quality.get("validation")
    if isinstance(nested, Mapping):
        lines += _record(nested)
    unpaired = quality.get("unpaired_fidelity")
    if isinstance(unpaired, Mapping):
        text = (
            f"bands log2 {_bands(unpaired.get('bands'))}, flat noise {_number(unpaired.get('noise_ratio'))}, "
            f"spectrum mismatch {_number(unpaired.get('spectrum_mismatch'), 3)}, image-only critic "
            f"{_number(_mapping(unpaired.get('critic_image_only')).get('accuracy'))} (the clean set simulated vs "
            "captures)"
        )
        lines += _labelled("unpaired", text)
    return lines


# --- the parts --------------------------------------------------------------------------------------------------


def _network(header: ProfileHeader) -> str:
    spec = header.metadata.get("network")
    if not isinstance(spec, Mapping):
        return "none: the profile holds effect stages only"
    config = _mapping(spec.get("config"))
    shown = [key if value is True else f"{key} {value}" for key, value in sorted(config.items()) if value is not False]
    parameters = sum(entry.numel for key, entry in header.tensors.items() if key.startswith("network."))
    return f"{printable(spec.get('arch'))} ({', '.join(shown)}): {parameters:,} parameters"


def _chain(header: ProfileHeader) -> list[str]:
    specs = header.metadata.get("effects") or []
    lines = _labelled("chain", f"{len(specs)} stage(s), in the order they run" if specs else "no effect stage")
    values = read_arrays(header.path, [key for key in header.tensors if key.startswith("effects.")])
    for index, spec in enumerate(specs):
        name = str(spec["name"])
        facts = effect_facts(name)
        mine = {key.rsplit(".", 1)[1]: array for key, array in values.items() if key.startswith(f"effects.{index}.")}
        items = _key_values(facts, _mapping(spec.get("config")), mine)
        lines.append(_filled(f"  {index}. {printable(name)} [{getattr(facts, 'stage', '?')}] ", items))
    return lines


def _filled(head: str, items: list[str]) -> str:
    """``head`` and as many of ``items`` as fit in :data:`WIDTH`, then how many more there are (``--json`` has
    them all)."""
    if not items:
        return head + "(defaults)"
    line = head + items[0]
    for index, item in enumerate(items[1:], start=1):
        more = f", +{len(items) - index - 1} more" if index < len(items) - 1 else ""
        if len(f"{line}, {item}{more}") > WIDTH:
            return _cut(f"{line}, +{len(items) - index} more")
        line = f"{line}, {item}"
    return _cut(line)


def _key_values(facts: Any, config: Mapping[str, Any], arrays: Mapping[str, Any]) -> list[str]:
    """A stage's fitted values that are not zero (scalars, then short vectors), its settings that differ from their
    defaults (leaving out those that only size or switch on a tensor), then the shapes of its larger tensors."""
    buffers = getattr(facts, "buffers", {})
    implied = {dim for buffer in buffers.values() for dim in buffer.shape if isinstance(dim, str)}
    implied |= {buffer.when for buffer in buffers.values() if buffer.when}
    scalars, vectors, shapes = [], [], []
    for key, array in arrays.items():
        flat = [float(value) for value in array.reshape(-1).tolist()]
        if array.size > _SHOWN:
            shapes.append(f"{key}=<{'x'.join(str(size) for size in array.shape)}>")
        elif any(flat):
            (scalars if array.ndim == 0 else vectors).append(
                f"{key}={_g(flat[0])}" if array.ndim == 0 else f"{key}=[{', '.join(_g(value) for value in flat)}]"
            )
    settings = getattr(facts, "settings", {})
    changed = [
        f"{key}={value}"
        for key, value in config.items()
        if key not in implied and not (key in settings and value == settings[key].default)
    ]
    return scalars + vectors + changed + shapes


def _fit(fitted: Mapping[str, Any]) -> list[str]:
    if not fitted:
        return []
    minutes = f"{_number(fitted.get('fit_minutes'))} min" if _is_number(fitted.get("fit_minutes")) else ""
    if fitted.get("unpaired") is True:
        text = f"unpaired: {fitted.get('captures')} captures, {fitted.get('clean_images')} clean images"
    elif "distilled_from" in fitted:
        images = fitted.get("images")
        images = f"{images} clean images" if _is_number(images) else printable(images)
        text = (
            f"distilled from {printable(fitted['distilled_from'])} (width {fitted.get('teacher_width')}) on "
            f"{images}, best epoch {fitted.get('best_epoch')}"
        )
    else:
        text = (
            f"{fitted.get('pairs')} pairs ({fitted.get('train_pairs')} training, {fitted.get('validation_pairs')} "
            f"validation), best epoch {fitted.get('best_epoch')}"
        )
    lines = _labelled("fit", ", ".join(part for part in (text, minutes) if part))
    if isinstance(fitted.get("data"), str):
        lines += _labelled("data", printable(fitted["data"]), most=1)
    kept, dropped = _steps(fitted)
    if kept or dropped:
        lines += _labelled("steps", f"kept: {', '.join(kept) or 'none'}; dropped: {', '.join(dropped) or 'none'}")
    return lines


def _steps(fitted: Mapping[str, Any]) -> tuple[list[str], list[str]]:
    """The fit's steps and candidate stages that record whether they were kept, in the order recorded; an unpaired
    fit lists the stages it kept (``kept``) and those it did not fit (``not_fitted``)."""
    records = [(key, value) for key, value in fitted.items() if key != "effects"]
    records += list(_mapping(fitted.get("effects")).items())
    kept, dropped = [], [printable(key) for key in _mapping(fitted.get("not_fitted"))]
    for key, value in records:
        if isinstance(value, Mapping) and isinstance(value.get("kept"), bool):
            (kept if value["kept"] else dropped).append(printable(key))
    if isinstance(fitted.get("kept"), list):
        kept = [printable(name) for name in fitted["kept"]]
    return kept, dropped


def _record(quality: Mapping[str, Any]) -> list[str]:
    label, pairs = _where(quality)
    psnr = _psnr(quality)
    if psnr is None:
        return []
    lines = _labelled(label, f"{pairs}PSNR {psnr}")
    fidelity = quality.get("fidelity")
    if isinstance(fidelity, Mapping):
        text = (
            f"fidelity: grid {_number(fidelity.get('grid_ratio'))}, bands log2 {_bands(fidelity.get('bands'))}, "
            f"flat noise {_number(fidelity.get('noise_ratio'))}, banding {_number(fidelity.get('banding_ratio'))} "
            "(sim/capture)"
        )
        lines += _labelled("", text) + _labelled("", f"critic: {_critics(fidelity)}")
    return lines


def _where(quality: Mapping[str, Any]) -> tuple[str, str]:
    for key, label in (("held_out_pairs", "held-out"), ("validation_pairs", "validation")):
        if _is_number(quality.get(key)):
            return label, f"{_number(quality[key], 0)} pairs: "
    if _is_number(quality.get("validation_images")):
        return "validation", f"{_number(quality['validation_images'], 0)} images: "
    return "quality", ""


def _psnr(quality: Mapping[str, Any]) -> str | None:
    """``identity 23.79 dB -> profile 30.81 dB (network 30.80 dB)``; a distilled profile's against its teacher."""
    profile = next((key for key in ("profile_psnr_db", "profile_psnr_mean_db") if key in quality), None)
    sampled, mean = quality.get("profile_psnr_db"), quality.get("profile_psnr_mean_db")
    if _is_number(sampled) and _is_number(mean) and f"{sampled:.2f}" != f"{mean:.2f}":  # a stage that draws
        main = f"profile {_db(mean)} mean, {_db(sampled)} sampled"
        if "identity_psnr_db" in quality:
            main = f"identity {_db(quality['identity_psnr_db'])} -> {main}"
    elif "identity_psnr_db" in quality and profile is not None:
        main = f"identity {_db(quality['identity_psnr_db'])} -> profile {_db(quality[profile])}"
    elif profile is not None:
        main = f"profile {_db(quality[profile])}"
    elif "student_vs_teacher_psnr_db" in quality:
        main = f"student vs teacher {_db(quality['student_vs_teacher_psnr_db'])}"
    else:
        return None
    others = [
        f"{label} {_db(quality[key])}"
        for label, key in (
            ("baseline", "baseline_psnr_db"),
            ("network", "network_psnr_db"),
            ("full profile", "full_profile_psnr_mean_db"),
            ("student vs teacher", "student_vs_teacher_psnr_db"),
        )
        if key in quality and not main.startswith(label)
    ]
    return f"{main} ({', '.join(others)})" if others else main


def _critics(fidelity: Mapping[str, Any]) -> str:
    parts, counts = [], set()
    for label, key in (("paired", "critic_paired"), ("image-only", "critic_image_only")):
        result = fidelity.get(key)
        if not isinstance(result, Mapping):
            parts.append(f"{label} not run")
            continue
        spread = f" ± {_number(result.get('std'))}" if _is_number(result.get("std")) else ""
        interval = f" [{_number(result.get('low'))}-{_number(result.get('high'))}]"
        parts.append(f"{label} {_number(result.get('accuracy'))}{spread}{interval}")
        counts.add(result.get("critics") if _is_number(result.get("critics")) else 1)
    counted = f"{_number(counts.pop(), 0)} critic(s); " if len(counts) == 1 else ""
    return f"{', '.join(parts)} ({counted}0.5: cannot tell)"


# --- text ---------------------------------------------------------------------------------------------------------


def _labelled(label: str, text: str, most: int | None = None) -> list[str]:
    """``text`` after ``label`` in its column, wrapped at :data:`WIDTH`; at most ``most`` lines (the last cut)."""
    lines = textwrap.wrap(
        text,
        WIDTH,
        initial_indent=f"{label:<{_LABEL - 1}} ",
        subsequent_indent=" " * _LABEL,
        break_on_hyphens=False,
    ) or [label]
    if most is not None and len(lines) > most:
        lines = [*lines[: most - 1], lines[most - 1][: WIDTH - 4] + " ..."]
    return [_cut(line) for line in lines]


def _cut(line: str) -> str:
    """``line``, or its first characters and `` ...`` where it is wider than :data:`WIDTH`."""
    return line if len(line) <= WIDTH else line[: WIDTH - 4] + " ..."


def _mapping(value: Any) -> Mapping[str, Any]:
    return value if isinstance(value, Mapping) else {}


def _versions(versions: Mapping[str, str | None]) -> str:
    return ", ".join(f"{package} {printable(version or '(not recorded)')}" for package, version in versions.items())


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _number(value: Any, digits: int = 2) -> str:
    """A number as text; anything else in the metadata (it comes from a file) as ``n/a``, never as itself."""
    return f"{value:.{digits}f}" if _is_number(value) else "n/a"


def _db(value: Any) -> str:
    return "inf dB (identical)" if value is None else f"{_number(value)} dB"


def _bands(bands: Any) -> str:
    if not isinstance(bands, list):
        return "n/a"
    return " ".join(f"{value:+.2f}" if _is_number(value) else "n/a" for value in bands)


def _g(value: float) -> str:
    return f"{value:.3g}"


def _rounded(value: Any) -> Any:
    if isinstance(value, list):
        return [_rounded(item) for item in value]
    return round(value, 6) if isinstance(value, float) else value
