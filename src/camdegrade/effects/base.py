"""The contract every camera-effect stage follows, and the registry the profile format and diagnosis use."""

from __future__ import annotations

import copy
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any, ClassVar, Literal, TypeAlias

import torch
from torch import Tensor, nn

from camdegrade.effects.linear import Encoding, LinearFilter

__all__ = [
    "EFFECTS",
    "STAGES",
    "Effect",
    "Encoding",
    "Pairs",
    "Stage",
    "build_effect",
    "check_effect_names",
    "check_range",
    "evenly_spaced",
    "register_effect",
    "shown",
]

#: Physical order of stages in a camera: light passes the optics, hits the sensor, is processed, then encoded.
STAGES: tuple[str, ...] = ("optics", "sensor", "isp", "codec")
Stage = Literal["optics", "sensor", "isp", "codec"]

#: What a fitter accepts: a float ``(N, 3, H, W)`` batch in [0, 1], or a sequence of ``(3, H, W)`` images
#: that may differ in size from pair to pair (uint8 is accepted too and scaled to [0, 1]).
Pairs: TypeAlias = "Tensor | Sequence[Tensor]"

#: name → Effect subclass. Filled by :func:`register_effect`; the names are the diagnosis vocabulary.
EFFECTS: dict[str, type[Effect]] = {}


class Effect(nn.Module):
    """One camera effect applied after the network: an ``nn.Module`` whose state is tensors.

    Contract (the profile format and the diagnosis rely on it):

    - Every fitted value is a registered buffer, so ``state_dict()`` holds it and safetensors can store it.
      ``config()`` returns the JSON-serialisable constructor arguments; ``type(e).from_config(e.config())``
      rebuilds a module with buffers of exactly the same shapes, ready for a strict ``load_state_dict``.
    - All randomness is drawn in :meth:`make_params` from the given ``torch.Generator`` (CPU), as tensors with a
      leading batch dimension ``N``; :meth:`forward` is deterministic given those params, so a degradation can be
      replayed exactly and a subset of a batch can be taken by indexing every param with the same index.
    - :meth:`forward` takes float ``(N, 3, H, W)`` in ``[0, 1]``, returns the same shape, dtype and device, and never
      modifies its input. Pure kernels live in :mod:`camdegrade.functional`.
    - Optionally, :meth:`encodings` and :meth:`forward_encoded` run the same stage in linear light and in place, so
      that a profile decodes sRGB once for a run of such stages (see :mod:`camdegrade.effects.chain`).

    Everything the rest of the package needs to know about an effect is asked of its class, never looked up by
    name elsewhere: :meth:`neutral` (the identity), :meth:`without_randomness` (its deterministic centre, or
    ``None`` for pure noise), :meth:`scaled` (its strength), :attr:`fit_budget` and :meth:`fit_options` (what its
    fitter affords), :meth:`fit_in_chain` (how it is fitted at its place in a profile), :meth:`linear_filter`
    (whether it is a linear shift-invariant filter, and which), :attr:`explains` (the gap
    signatures it can cause), :attr:`candidate` (whether the diagnosis tries it unasked), :attr:`position_dependent`,
    :attr:`moves_pixels` with :meth:`source_points` and :meth:`moved_points` (how it moves positions, so targets
    move with the image) and :meth:`check_values` (the valid ranges of its values, checked when a profile is loaded
    or saved). The registry-wide tests in
    ``tests/test_effects.py`` and ``tests/test_architecture.py`` hold every registered effect to this contract.
    """

    name: ClassVar[str] = ""
    stage: ClassVar[Stage] = "isp"
    #: The statistic families (names registered in :mod:`camdegrade.measures`) whose signature this effect leaves when
    #: a profile lacks it or has it wrong; the registry-wide tests check every name.
    explains: ClassVar[tuple[str, ...]] = ()
    #: At most this many pairs go to :meth:`fit` when the diagnosis fits it as a candidate (``None``: all).
    fit_budget: ClassVar[int | None] = None
    #: Whether it varies over the frame, which a translation-equivariant network cannot learn: ``fit_profile``
    #: keeps such a stage only where it lowers the validation error.
    position_dependent: ClassVar[bool] = False
    #: Whether it moves image content (a warp): such an effect says how it moves positions with
    #: :meth:`source_points` and :meth:`moved_points`, and targets (masks, boxes, keypoints) are moved with it.
    moves_pixels: ClassVar[bool] = False
    #: Whether the diagnosis tries adding it when its caller names no candidates: false for a stage so free that it
    #: would stand in for the effect the camera has instead of naming it.
    candidate: ClassVar[bool] = True

    @classmethod
    def neutral(cls) -> Effect:
        """An instance that leaves every image unchanged (default: the constructor's defaults)."""
        return cls()

    def without_randomness(self) -> Effect | None:
        """This stage's deterministic centre: the profile's conditional mean keeps it, candidate effects are fitted
        against it. A copy without per-sample jitter, or ``None`` for a stage that only adds zero-mean noise.
        Default: the stage itself (it draws nothing)."""
        return self

    def scaled(self, strength: float) -> Effect:
        """A copy whose fitted values are moved from :meth:`neutral`'s by ``strength`` times their change
        (0: neutral, 1: as fitted)."""
        neutral = type(self).neutral().state_dict()
        state = {
            key: neutral[key] + strength * (value - neutral[key]) if key in neutral else value
            for key, value in self.state_dict().items()
        }
        out = copy.deepcopy(self)
        out.load_state_dict(state)
        return out

    def simplified(self) -> list[Effect]:
        """Simpler versions of this stage, each with one of its parts switched off (noise without its banding,
        say), which a refit tries beside a fresh fit. Default: none."""
        return []

    def magnitude(self) -> float:
        """How far this stage is from :meth:`neutral`: the L2 norm of its buffers' change (in their own units).
        Ratios of two stages of one kind say how much stronger one is; effects with a natural measure override it
        (noise: its std at mid-grey in 8-bit levels)."""
        neutral = type(self).neutral().state_dict()
        squares = [
            float((value.double() - neutral[key].double()).pow(2).sum())
            for key, value in self.state_dict().items()
            if key in neutral and value.is_floating_point()
        ]
        return sum(squares) ** 0.5

    @classmethod
    def fit_options(cls, images: Sequence[Tensor]) -> dict[str, Any]:
        """Options for :meth:`fit` on these (possibly few or small) source images; default none."""
        return {}

    def make_params(
        self, shape: torch.Size | tuple[int, ...], generator: torch.Generator | None = None
    ) -> dict[str, Tensor]:
        """Draw this stage's random values for a batch of ``shape = (N, 3, H, W)``. Deterministic stages: ``{}``."""
        return {}

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        raise NotImplementedError

    def source_points(
        self, x: Tensor, y: Tensor, size: tuple[int, int], params: Mapping[str, Tensor]
    ) -> tuple[Tensor, Tensor]:
        """Where in this stage's input the output positions ``(x, y)`` read from (the sampling grid of a warp).

        Positions are centred pixel coordinates (x right, y down, in pixels from the centre of an image of
        ``size = (H, W)``), shaped ``(N, P)`` for the ``N`` frames ``params`` were drawn for (or ``(1, P)``).
        Default: the same positions (a stage that does not move pixels, :attr:`moves_pixels` false).
        """
        return x, y

    def moved_points(
        self, x: Tensor, y: Tensor, size: tuple[int, int], params: Mapping[str, Tensor]
    ) -> tuple[Tensor, Tensor]:
        """Where this stage puts the input positions ``(x, y)``: the inverse of :meth:`source_points` (same
        coordinates and shapes), which moves keypoints and boxes. Default: the same positions."""
        return x, y

    def encodings(self) -> tuple[Encoding, Encoding]:
        """The encodings of :meth:`forward_encoded`'s input and output. sRGB for both unless overridden."""
        return ("srgb", "srgb")

    def forward_encoded(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        """The stage on a float ``image`` already in ``encodings()[0]``, returning values in ``encodings()[1]``.

        For inference without autograd: the caller owns ``image`` and this may overwrite it. A profile runs
        consecutive linear-light stages this way with one sRGB decode and one encode around them; the result
        equals :meth:`forward` up to float rounding (tested for every effect). Default: :meth:`forward`.
        """
        return self.forward(image, params)

    def linear_filter(self) -> LinearFilter | None:
        """This stage as a linear shift-invariant filter of the values in its encoding (:meth:`encodings`), when it
        is one and draws nothing: a profile's chain then composes it with the adjacent such stages into one filter
        at inference (:mod:`camdegrade.effects.plan`), which must equal running them one by one up to float rounding
        (tested for every effect). ``None`` (the default) for a stage that is not: coring, curves, noise, warps,
        quantisation, per-sample draws."""
        return None

    def config(self) -> dict[str, Any]:
        """JSON-serialisable constructor arguments (not the fitted tensors, which are buffers)."""
        return {}

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> Effect:
        return cls(**config)

    @classmethod
    def fit(cls, source: Pairs, target: Pairs, **options: Any) -> Effect:
        """Estimate this effect from aligned pairs: ``target ≈ effect(source)``.

        ``source`` is the clean (or simulated) image, ``target`` the real capture; both are :data:`Pairs`.
        Each effect documents its estimator, its options and its stated recovery tolerance.
        """
        raise NotImplementedError(f"effect {cls.name!r} ({cls.__qualname__}) has no fitter")

    @classmethod
    def has_pair_fitter(cls) -> bool:
        """Whether :meth:`fit` is implemented (a stage trained otherwise, such as a learned one, has none)."""
        return cls.fit.__func__ is not Effect.fit.__func__  # type: ignore[attr-defined]

    @classmethod
    def fit_in_chain(
        cls,
        cleans: Sequence[Tensor],
        sources: Sequence[Tensor],
        captures: Sequence[Tensor],
        simulate_with: Callable[[Effect, Sequence[int]], list[Tensor]],
        *,
        seed: int = 0,
        calibration_pairs: int | None = None,
    ) -> Effect:
        """Fit this effect where it sits in a profile.

        ``sources`` are the profile's deterministic output on the clean images ``cleans``, ``captures`` the real
        captures; ``simulate_with(effect, indices)`` simulates the profile with ``effect`` in place of its stages of
        this kind on the clean images at ``indices`` (fixed seeds: the same effect gives the same images).
        ``calibration_pairs`` bounds about how many pairs a fit that simulates may use. Default: :meth:`fit` on
        the pairs its fitter affords (:attr:`fit_budget`) with its :meth:`fit_options`. An effect whose look
        depends on the stages after it (noise, through a tone curve and a codec) overrides this to calibrate
        through ``simulate_with``.
        """
        return cls.fit_within_budget(sources, captures)

    @classmethod
    def fit_within_budget(cls, sources: Sequence[Tensor], targets: Sequence[Tensor]) -> Effect:
        """:meth:`fit` on at most :attr:`fit_budget` evenly spaced pairs, with the :meth:`fit_options` for them."""
        if cls.fit_budget is not None:
            sources, targets = evenly_spaced(sources, cls.fit_budget), evenly_spaced(targets, cls.fit_budget)
        return cls.fit(list(sources), list(targets), **cls.fit_options(list(sources)))

    @classmethod
    def calibrates_in_chain(cls) -> bool:
        """Whether :meth:`fit_in_chain` is its own (it calibrates through the stages after it, by simulating them):
        the diagnosis then fits it that way rather than on the profile's output alone."""
        return cls.fit_in_chain.__func__ is not Effect.fit_in_chain.__func__  # type: ignore[attr-defined]

    @classmethod
    def draws_only_noise(cls) -> bool:
        """Whether stages of this kind only add zero-mean noise: their deterministic centre is nothing
        (:meth:`without_randomness` is ``None``), so they are fitted through the chain (:meth:`fit_in_chain`) and a
        fitted one replaces the profile's rather than adding to it."""
        return cls.neutral().without_randomness() is None

    def check_values(self) -> None:
        """Raise ``ValueError`` naming the first value outside its valid range: profiles are checked when they are
        loaded (values come from a file) and saved. Default: every floating-point buffer is finite. Effects add
        their own ranges (and those of their ``config()`` numbers) with :func:`check_range`."""
        for key, value in self.named_buffers():
            if value.is_floating_point() and not bool(torch.isfinite(value).all()):
                raise ValueError(f"{key} must be finite, got {key}={shown(value)}")

    def extra_repr(self) -> str:
        items = [f"{key}={value!r}" for key, value in self.config().items()]
        for key, value in self.named_buffers(recurse=False):
            if value.numel() <= 9:
                rounded = [round(v, 6) for v in value.flatten().tolist()]
                items.append(f"{key}={rounded[0] if value.ndim == 0 else rounded}")
        return ", ".join(items)


def evenly_spaced(items: Sequence[Any], limit: int) -> list[Any]:
    """At most ``limit`` of ``items``, evenly spaced (all of them when there are no more)."""
    if len(items) <= limit:
        return list(items)
    step = len(items) / limit
    return [items[int(i * step)] for i in range(limit)]


def check_range(name: str, value: Tensor | float, low: float, high: float, *, low_open: bool = False) -> None:
    """Raise ``ValueError`` unless every element of ``value`` is finite and in ``[low, high]`` (``(low, high]`` with
    ``low_open``), naming ``name`` and the value found."""
    tensor = torch.as_tensor(value, dtype=torch.float64)
    below = tensor <= low if low_open else tensor < low
    if bool((~torch.isfinite(tensor) | below | (tensor > high)).any()):
        bound = f"from {low:g}{' (exclusive)' if low_open else ''} to {high:g}"
        raise ValueError(f"{name} must be {bound}, got {name}={shown(tensor)}")


def shown(value: Tensor) -> str:
    """A buffer's value for an error message: a number, or a short list."""
    if value.ndim == 0:
        return f"{value.item():.6g}"
    items = [round(v, 6) for v in value.flatten().tolist()[:9]]
    return f"{items}" if value.numel() <= 9 else f"{items[:-1]} ... ({value.numel()} values)"


def register_effect(cls: type[Effect]) -> type[Effect]:
    """Class decorator adding an effect to :data:`EFFECTS` under ``cls.name``."""
    if not cls.name:
        raise ValueError(f"{cls.__qualname__} must set a non-empty class attribute 'name'")
    if cls.stage not in STAGES:
        raise ValueError(f"{cls.__qualname__}.stage must be one of {STAGES}, got {cls.stage!r}")
    if cls.name in EFFECTS and EFFECTS[cls.name] is not cls:
        raise ValueError(f"an effect named {cls.name!r} is already registered ({EFFECTS[cls.name].__qualname__})")
    EFFECTS[cls.name] = cls
    return cls


def check_effect_names(names: Iterable[str] | str, what: str = "effects") -> list[str]:
    """``names`` as a list, each a registered effect name; else a ``ValueError`` naming ``what`` and the unknown
    names (a single name given as a string is one name, not its letters)."""
    listed = [names] if isinstance(names, str) else list(names)
    unknown = [name for name in listed if name not in EFFECTS]
    if unknown:
        raise ValueError(f"{what} must be effect names from {sorted(EFFECTS)}, got unknown {unknown}")
    return listed


def build_effect(name: str, config: Mapping[str, Any] | None = None) -> Effect:
    """Instantiate the registered effect ``name`` from its ``config()``."""
    if name not in EFFECTS:
        known = ", ".join(sorted(EFFECTS)) or "none"
        raise KeyError(f"unknown effect {name!r}; registered effects: {known}")
    return EFFECTS[name].from_config(dict(config or {}))
