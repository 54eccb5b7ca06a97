"""Camera profiles: a fitted network plus an ordered chain of camera effects, stored as safetensors."""

from __future__ import annotations

import copy
import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError, safe_open
from safetensors.torch import save_file
from torch import Tensor, nn

from camdegrade._files import atomic_path
from camdegrade._outputs import OUTPUTS, ProfileKeys, image_key
from camdegrade._pixels import bytes_to_unit, unit_to_bytes
from camdegrade._profile_format.check import listing, network_class, network_config
from camdegrade._profile_format.header import FORMAT_NAME as FORMAT_NAME
from camdegrade._profile_format.header import FORMAT_VERSION as FORMAT_VERSION
from camdegrade._profile_format.header import MAX_EFFECTS as MAX_EFFECTS
from camdegrade._profile_format.header import METADATA_KEY as METADATA_KEY
from camdegrade._profile_format.header import builtin_profiles_dir as builtin_profiles_dir
from camdegrade._profile_format.header import list_profiles as list_profiles
from camdegrade._profile_format.header import read_header
from camdegrade._profile_format.header import resolve_profile_path as resolve_profile_path
from camdegrade._profile_format.header import serialize_metadata as serialize_metadata
from camdegrade._seeds import derived_generator
from camdegrade._version import __version__
from camdegrade.effects import STAGES, Effect, build_effect
from camdegrade.effects.chain import apply_effects, check_chain, check_params
from camdegrade.errors import ProfileError
from camdegrade.inference import Precision, run_network
from camdegrade.network import ARCHITECTURES, ShiftNetwork

__all__ = ["CameraProfile", "EffectParams", "as_profile", "check_profile_values", "load_profile"]

EffectParams = list[dict[str, Tensor]]


class CameraProfile(nn.Module):
    """A camera's degradation: the clean → captured network, then its effect stages, plus metadata.

    Args:
        network: the fitted network (:class:`DomainShiftNet` or :class:`LocalAffineNet`), or ``None`` for a
            profile made of effect stages only.
        effects: effect stages applied after the network, in physical order (optics → sensor → ISP → codec).
        name: short identifier, e.g. ``"city100-iphonex"``.
        description: one line for humans.
        fitted: how the profile was fitted (data, recipe, seed, ...), JSON-serialisable.
        quality: held-out quality numbers (e.g. PSNR against the captures), JSON-serialisable.

    Shape:
        - Input: ``(N, 3, H, W)``, float in ``[0, 1]``, or uint8 (read as ``value / 255``).
        - Output: ``(N, 3, H, W)``, float32 in ``[0, 1]``.

    Examples:
        >>> from camdegrade import DomainShiftNet
        >>> profile = CameraProfile(DomainShiftNet(), name="untrained")
        >>> profile(torch.rand(1, 3, 8, 8)).shape
        torch.Size([1, 3, 8, 8])
    """

    def __init__(
        self,
        network: ShiftNetwork | None,
        effects: Sequence[Effect] = (),
        *,
        name: str = "",
        description: str = "",
        fitted: Mapping[str, Any] | None = None,
        quality: Mapping[str, Any] | None = None,
        package_version: str = __version__,
    ) -> None:
        super().__init__()
        if network is not None and not isinstance(network, ShiftNetwork):
            raise TypeError(f"network must be a DomainShiftNet, a LocalAffineNet or None, got {type(network).__name__}")
        check_chain(effects)
        for label, text in (("name", name), ("description", description), ("package_version", package_version)):
            if not isinstance(text, str):  # a profile file stores text; None would come back as 'None'
                raise TypeError(f"{label} must be a str, got {label}={text!r} ({type(text).__name__})")
        for label, record in (("fitted", fitted), ("quality", quality)):
            if record is not None and not isinstance(record, Mapping):
                raise TypeError(f"{label} must be a mapping (JSON object) or None, got {type(record).__name__}")
        self.network = network
        self.effects = nn.ModuleList(effects)
        self.name = name
        self.description = description
        self.fitted = dict(fitted or {})
        self.quality = dict(quality or {})
        self.package_version = package_version
        self.requires_grad_(False)
        self.eval()

    @property
    def effect_names(self) -> list[str]:
        return [effect.name for effect in self.effects]

    def make_params(
        self, shape: torch.Size | tuple[int, ...], generator: torch.Generator | None = None
    ) -> EffectParams:
        """Draw every effect's random values for a batch of ``shape = (N, 3, H, W)``, in chain order."""
        return [effect.make_params(tuple(shape), generator) for effect in self.effects]

    def forward(self, image: Tensor, params: EffectParams | None = None, *, precision: Precision = "float32") -> Tensor:
        """Degrade ``image``; ``params`` from :meth:`make_params` (drawn from the global RNG when omitted);
        ``precision`` of the network (see :func:`camdegrade.inference.run_network`)."""
        if params is None:
            params = self.make_params(image.shape)
        check_params(self.effects, params)
        if image.numel() == 0:  # empty in, empty out (the network cannot pad an image without pixels)
            return torch.zeros(image.shape, dtype=torch.float32, device=image.device)
        owned = False  # whether ``image`` is a tensor this call made, which it may overwrite
        if self.network is not None:
            image, owned = run_network(self.network, image, precision), True
        elif image.dtype == torch.uint8:
            image, owned = bytes_to_unit(image), True
        return self._stages(image, params, owned)

    def _stages(self, image: Tensor, params: EffectParams, owned: bool) -> Tensor:
        """The effect stages and the final clamp on ``image`` (the network's output, or the input without one),
        overwritten when ``owned``."""
        if self.effects:
            image, owned = apply_effects(self.effects, params, image, overwrite=owned), True
        return image.clamp_(0.0, 1.0) if owned and not image.requires_grad else image.clamp(0.0, 1.0)

    def simulate(
        self,
        images: Sequence[Tensor],
        seed: int,
        *,
        stream: str = "simulate",
        deterministic: bool = False,
        eight_bit: bool = False,
    ) -> list[Tensor]:
        """This profile applied to each image ``(3, H, W)``, image ``i`` drawing from ``(seed, stream, i)``
        (:func:`~camdegrade._seeds.derived_generator`): the same images for the same seed in any process, whatever
        else is simulated around them. The one seeded simulation of fitting, diagnosis and the unpaired fit.

        ``deterministic`` runs the deterministic part (:meth:`without_randomness`): the conditional mean that
        candidate stages are fitted against. ``eight_bit`` rounds each output to 8-bit values, as a file stores it.

        Outputs computed before come from :mod:`camdegrade._outputs` (the same bytes): a profile that draws nothing
        gives an image one output whatever the seed or stream, and every profile with one network gives it one
        network output.
        """
        profile = self.without_randomness() if deterministic else self
        keys = ProfileKeys(profile)
        out = []
        with torch.no_grad():
            for index, image in enumerate(images):
                params = profile.make_params(image[None].shape, derived_generator(seed, stream, index))
                output = profile._simulated(image, params, keys)
                out.append(bytes_to_unit(unit_to_bytes(output)) if eight_bit else output)
        return out

    def _simulated(self, image: Tensor, params: EffectParams, keys: ProfileKeys) -> Tensor:
        """``self(image[None], params)[0]``, from the cache where it can be: the whole output when the profile draws
        nothing, else its network's output with the stages run after it as :meth:`forward` runs them."""
        if self.network is None or image.requires_grad or image.numel() == 0:
            return self(image[None], params)[0]
        if not any(params):
            key = ("profile", keys.whole(), image_key(image))
            output = OUTPUTS.get(key)
            if output is None:
                output = self(image[None], params)[0]
                OUTPUTS.put(key, image, output)
            return output
        key = ("network", keys.network(), image_key(image))
        network_output = OUTPUTS.get(key)
        if network_output is None:
            network_output = run_network(self.network, image[None])
            OUTPUTS.put(key, image, network_output)
        check_params(self.effects, params)
        return self._stages(network_output, params, owned=True)[0]

    def with_effects(self, *effects: Effect) -> CameraProfile:
        """A copy of this profile with ``effects`` added, each inserted after the last stage of its kind or earlier."""
        chain = list(self.effects)
        for effect in effects:
            rank = STAGES.index(effect.stage)
            position = sum(1 for existing in chain if STAGES.index(existing.stage) <= rank)
            chain.insert(position, effect)
        return self.with_chain(chain)

    def with_chain(self, effects: Sequence[Effect]) -> CameraProfile:
        """A copy of this profile (network and metadata) with the effect chain ``effects`` (copied) instead."""
        return CameraProfile(
            copy.deepcopy(self.network),
            copy.deepcopy(list(effects)),
            name=self.name,
            description=self.description,
            fitted=self.fitted,
            quality=self.quality,
            package_version=self.package_version,
        )

    def without_randomness(self) -> CameraProfile:
        """The deterministic part: every stage replaced by its :meth:`~Effect.without_randomness` centre, stages
        that only add noise left out (the conditional mean a capture scatters around). Metadata is kept."""
        centres = [effect.without_randomness() for effect in self.effects]
        return self.with_chain([centre for centre in centres if centre is not None])

    def metadata(self) -> dict[str, Any]:
        """Everything but the tensors. Stored as canonical JSON under the one safetensors metadata key
        :data:`METADATA_KEY` (safetensors writes several keys in arbitrary order, which would make equal profiles
        differ in bytes)."""
        network = self.network
        network = None if network is None else {"arch": type(network).__name__, "config": network.config()}
        return {
            "format": FORMAT_NAME,
            "format_version": FORMAT_VERSION,
            "name": self.name,
            "description": self.description,
            "package_version": self.package_version,
            "network": network,
            "effects": [
                {"name": effect.name, "stage": effect.stage, "config": effect.config()} for effect in self.effects
            ],
            "fitted": self.fitted,
            "quality": self.quality,
        }

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the profile as one safetensors file, atomically (a temp file renamed into place)."""
        path = Path(path)
        if path.suffix != ".safetensors":
            raise ValueError(f"path must end in '.safetensors', got {str(path)!r}")
        label = f"cannot save profile {self.name or '(unnamed)'!r}"
        meta = [key for key, value in self.state_dict().items() if value.is_meta]
        if meta:
            raise ValueError(f"{label}: tensors on the meta device hold no values ({listing(meta)})")
        try:
            check_profile_values(self)
            metadata = serialize_metadata(self.metadata())  # before anything is written
        except ValueError as error:
            raise ValueError(f"{label}: {error}") from None
        except TypeError as error:  # json: a set, a tensor, ... in fitted or quality
            raise TypeError(f"{label}: its metadata (fitted, quality) must be JSON-serialisable: {error}") from None
        except RecursionError:
            raise ValueError(f"{label}: its metadata (fitted, quality) is nested too deeply to store") from None
        tensors = {key: _storable(value) for key, value in self.state_dict().items()}
        try:
            with atomic_path(path) as temporary:
                save_file(tensors, str(temporary), metadata=metadata)
        except SafetensorError as error:  # safetensors' own I/O errors (e.g. a folder nothing can be created in)
            raise OSError(f"cannot write {str(path)!r}: {error}") from error
        return path

    def describe(self) -> str:
        """A few lines for humans: name, network, effect chain, how it was fitted, held-out quality."""
        # the config's keys sorted, as the file stores them and as the torch-free ``camdegrade info`` shows them
        config = None if self.network is None else dict(sorted(self.network.config().items()))
        network = "none" if self.network is None else f"{type(self.network).__name__}({config})"
        lines = [
            f"name:        {self.name or '(unnamed)'}",
            f"description: {self.description or '-'}",
            f"network:     {network}",
            f"effects:     {len(self.effects)}",
        ]
        lines += [
            f"  {i}. {effect.name} [{effect.stage}] {effect.extra_repr()}" for i, effect in enumerate(self.effects)
        ]
        lines.append(f"fitted:      {json.dumps(self.fitted, sort_keys=True)}")
        lines.append(f"quality:     {json.dumps(self.quality, sort_keys=True)}")
        lines.append(f"written by:  camdegrade {self.package_version}")
        return "\n".join(lines)

    def extra_repr(self) -> str:
        return f"name={self.name!r}"


def check_profile_values(profile: CameraProfile) -> None:
    """Raise ``ValueError`` naming the first value that is out of range: a network weight that is not finite, or
    an effect value outside what its :meth:`~camdegrade.effects.Effect.check_values` allows."""
    if profile.network is not None:
        for key, value in profile.network.state_dict().items():
            if value.is_floating_point() and not bool(torch.isfinite(value).all()):
                bad = int((~torch.isfinite(value)).sum())
                raise ValueError(f"network.{key} must be finite, got {bad} NaN or infinite values")
    for index, effect in enumerate(profile.effects):
        try:
            effect.check_values()
        except ValueError as error:
            raise ValueError(f"effect {index} ({effect.name}): {error}") from None


def _storable(value: Tensor) -> Tensor:
    """A tensor as a profile file stores it: on the CPU, contiguous, half precisions widened to float32."""
    value = value.detach().cpu()
    if value.dtype in (torch.float16, torch.bfloat16):
        value = value.float()
    return value.contiguous().clone()


def load_profile(name_or_path: str | os.PathLike[str], device: torch.device | str | None = None) -> CameraProfile:
    """Load a built-in profile by name, or a profile file by path, strictly.

    Only regular safetensors files are read (pickled checkpoints are refused, never unpickled). The file is checked
    whole before anything is built, as ``camdegrade info`` checks it
    (:func:`camdegrade._profile_format.header.read_header`): the format version; the network's width (at most
    :data:`~camdegrade.network.MAX_WIDTH`); each effect entry (a known effect, its stage, its config keys, their
    types and ranges); every tensor the profile needs, with the right shape and a float dtype, nothing left over;
    network weights finite; every effect value in its range. Anything wrong is a one-line
    :class:`~camdegrade.errors.ProfileError`. The built profile's values are checked once more
    (:meth:`~camdegrade.effects.Effect.check_values`).

    Examples:
        >>> load_profile("city100-iphonex").name
        'city100-iphonex'
    """
    header = read_header(name_or_path)
    header.check_values()
    path = header.path
    profile = _profile_from_metadata(header.metadata, path)
    try:
        with safe_open(str(path), framework="pt", device="cpu") as handle:
            tensors = {key: handle.get_tensor(key) for key in handle.keys()}  # noqa: SIM118 - safe_open has no iter
    except SafetensorError as error:
        raise ProfileError(
            f"profile file {str(path)!r} is corrupt or truncated ({error}); fit or copy it again"
        ) from error
    if profile.network is not None:
        profile.network.to_empty(device="cpu")  # built on the meta device; the file's weights fill it below
    try:
        profile.load_state_dict(tensors, strict=True)
        check_profile_values(profile)
    except (RuntimeError, ValueError) as error:  # only if the file changed since read_header checked it
        raise ProfileError(f"profile {str(path)!r}: {error}") from None
    return profile if device is None else profile.to(device)


def as_profile(profile: CameraProfile | str | os.PathLike[str]) -> CameraProfile:
    """``profile`` itself, or the profile a built-in name or a file path refers to (:func:`load_profile`)."""
    if isinstance(profile, CameraProfile):
        return profile
    if isinstance(profile, (str, os.PathLike)):
        return load_profile(profile)
    raise TypeError(f"profile must be a CameraProfile, a profile name or a path, got {type(profile).__name__}")


def _profile_from_metadata(metadata: Mapping[str, Any], path: Path) -> CameraProfile:
    """The profile the (checked) ``metadata`` describes: its network on the meta device, its effects with their
    constructors' values (the file's tensors replace both)."""
    network = _network_from_spec(metadata.get("network"), path)
    effects = [build_effect(spec["name"], spec.get("config", {})) for spec in metadata.get("effects", [])]
    return CameraProfile(
        network,
        effects,
        name=str(metadata.get("name", "")),
        description=str(metadata.get("description", "")),
        fitted=metadata.get("fitted", {}),
        quality=metadata.get("quality", {}),
        package_version=str(metadata.get("package_version", "unknown")),
    )


def _network_from_spec(spec: Any, path: Path) -> ShiftNetwork | None:
    if spec is None:
        return None
    cls = next(cls for cls in ARCHITECTURES.values() if cls.__name__ == network_class(spec, path))
    config = network_config(spec, path)
    with torch.device("meta"):  # no memory spent on weights the file replaces
        return cls(**config)
