"""The contract every statistic family follows, and the one registry both diagnosis modes read.

A **family** is one kind of evidence about a camera's degradation (the tone residual, the noise level on flat
pixels, the transfer function, ...). Everything the rest of the package needs to know about it is on its class:

- :attr:`Family.name`, :attr:`Family.tau` (the difference worth one gap unit), :attr:`Family.unit` and
  :attr:`Family.description` (what it measures, in words);
- which effects it signals: each effect names the families it explains (``Effect.explains``, by name), and
  :meth:`Family.suspects` asks the effect registry; the registry-wide tests check every name an effect uses is a
  registered family;
- which of the network's own faults it signals (:attr:`Family.network_fault`, empty when none);
- for a **paired** family (measured on an image against the clean image it came from, :class:`PairedFamily`): how
  one pair is measured into sums (:meth:`~PairedFamily.measure`), how sums become values
  (:meth:`~PairedFamily.reduce`), the scale values are compared on (:meth:`~PairedFamily.compare`) and how a real
  and a simulated value read to a person (:meth:`~PairedFamily.describe`);
- for a **no-reference** family (one image alone, the unpaired mode, :class:`NoReferenceFamily`): its value on one
  image (:meth:`~NoReferenceFamily.measure`) and the paired family whose signature it carries
  (:attr:`~NoReferenceFamily.signature`, which says what it suspects).

Adding a family is one class in one module of this package (imported by its ``__init__``) plus its test.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import ClassVar, Protocol, TypeVar

from torch import Tensor

from camdegrade.effects import EFFECTS
from camdegrade.functional.analysis.images import flat_mask

__all__ = [
    "FAMILIES",
    "NO_REFERENCE",
    "Family",
    "FamilyClass",
    "MeasuredPair",
    "MeasuredSums",
    "NoReferenceFamily",
    "PairedFamily",
    "check_explains",
    "register_family",
]

T = TypeVar("T")


class MeasuredPair:
    """One image ``(3, H, W)`` against its clean image, float in [0, 1], and the intermediate results that several
    families share (computed once per pair: :meth:`shared`)."""

    def __init__(self, image: Tensor, clean: Tensor, mask: Tensor | None = None) -> None:
        self.image = image.float().clamp(0, 1)
        self.clean = clean.float().clamp(0, 1)
        self._mask = mask
        self._shared: dict[Callable, object] = {}

    @property
    def mask(self) -> Tensor:
        """The clean image's :func:`~camdegrade.functional.analysis.images.flat_mask` (computed when not given)."""
        if self._mask is None:
            self._mask = flat_mask(self.clean)
        return self._mask

    def shared(self, compute: Callable[[MeasuredPair], T]) -> T:
        """``compute(self)``, computed once for this pair whichever family asks first."""
        if compute not in self._shared:
            self._shared[compute] = compute(self)
        return self._shared[compute]  # type: ignore[return-value]


class MeasuredSums(Protocol):
    """The per-pair sums of every family over a set of images (what
    :class:`~camdegrade.measures.statistics.StatisticSet` holds), as a family's description reads the counts."""

    sums: dict[str, tuple[Tensor, Tensor]]


class Family:
    """One statistic family (see the module docstring). Subclass :class:`PairedFamily` or
    :class:`NoReferenceFamily` and register the class with :func:`register_family`."""

    name: ClassVar[str] = ""
    #: The difference (in :attr:`unit`, on the :meth:`PairedFamily.compare` scale) worth one gap unit.
    tau: ClassVar[float] = 0.0
    unit: ClassVar[str] = ""
    #: What the statistic is, in one line (``docs/diagnosis.md`` lists them).
    description: ClassVar[str] = ""
    #: The network's own artefact this family shows (why a significant score sends the network to a fine-tune),
    #: or empty when the network leaves no signature here.
    network_fault: ClassVar[str] = ""
    #: Whether every stage that leaves its signature here mixes neighbouring pixels (the transfer function).
    mixing: ClassVar[bool] = False
    #: Whether the statistic is a pattern at the pixel scale (the noise's next-pixel correlation, 8×8 block edges),
    #: which a stage mixing neighbouring pixels changes: an effect with this signature looks different on either side
    #: of such a stage (the diagnosis tries it on both, :mod:`camdegrade.diagnose.attribution.placement`).
    pixel_pattern: ClassVar[bool] = False
    #: Whether the statistic is where things are (a displacement registered against the clean image), which neither a
    #: symmetric transfer function nor the tone nor independent noise moves: a change that moves it names a geometric
    #: cause whatever its resampling does to the texture (:mod:`camdegrade.diagnose.attribution.signature`).
    geometric: ClassVar[bool] = False
    paired: ClassVar[bool] = True

    def suspects(self) -> list[str]:
        """The registered effects that name this family in ``Effect.explains`` and that the diagnosis tries unasked
        (``Effect.candidate``): a hint; the ranking decides."""
        return [name for name, effect in EFFECTS.items() if self.name in effect.explains and effect.candidate]


class PairedFamily(Family):
    """A family measured on an image against the clean image it came from, kept per pair as sums ``(num, den)``
    so that a set's value (sums over pairs, then :meth:`reduce`) can be recomputed on any bootstrap resample."""

    def measure(self, pair: MeasuredPair) -> tuple[Tensor, Tensor]:
        """This pair's sums ``(num, den)``, each a float tensor of a fixed shape."""
        raise NotImplementedError

    def reduce(self, num: Tensor, den: Tensor) -> Tensor:
        """Sums (over pairs) → values; NaN where there is too little data."""
        raise NotImplementedError

    def compare(self, values: Tensor) -> Tensor:
        """The scale real and simulated values are differenced on (default: as they are)."""
        return values

    def describe(self, real: Tensor, sim: Tensor, real_set: MeasuredSums) -> str:
        """How the real and the simulated values read to a person (``real_set`` for the counts behind them)."""
        raise NotImplementedError


class NoReferenceFamily(Family):
    """A family measured on one image alone (the unpaired mode: captures of other scenes than the clean images)."""

    paired: ClassVar[bool] = False
    #: The paired family whose signature this one carries: its suspects are this one's.
    signature: ClassVar[str] = ""

    def measure(self, image: Tensor) -> Tensor:
        """This image's values (a 1-D float tensor of a fixed length)."""
        raise NotImplementedError

    def suspects(self) -> list[str]:
        return FAMILIES[self.signature].suspects()


#: name → paired family (the statistic families of the paired diagnosis), in registration order.
FAMILIES: dict[str, PairedFamily] = {}
#: name → no-reference family (the unpaired diagnosis), in registration order.
NO_REFERENCE: dict[str, NoReferenceFamily] = {}


def check_explains() -> None:
    """Raise ``ValueError`` naming the first registered effect whose ``explains`` names an unregistered family
    (effects cannot import this package, so the check runs where families are used: at the start of a diagnosis)."""
    for effect in EFFECTS.values():
        unknown = [name for name in effect.explains if name not in FAMILIES]
        if unknown:
            raise ValueError(
                f"{effect.__qualname__}.explains must hold statistic family names from {list(FAMILIES)}, got {unknown}"
            )


FamilyClass = TypeVar("FamilyClass", bound=type[Family])


def register_family(cls: FamilyClass) -> FamilyClass:
    """Class decorator adding one instance of a family to :data:`FAMILIES` (paired) or :data:`NO_REFERENCE`."""
    if not cls.name:
        raise ValueError(f"{cls.__qualname__} must set a non-empty class attribute 'name'")
    if not cls.tau > 0:
        raise ValueError(f"{cls.__qualname__}.tau must be positive, got {cls.tau!r}")
    registry: dict = FAMILIES if cls.paired else NO_REFERENCE
    if cls.name in registry and type(registry[cls.name]) is not cls:
        raise ValueError(f"a family named {cls.name!r} is already registered ({type(registry[cls.name]).__qualname__})")
    registry[cls.name] = cls()
    return cls
