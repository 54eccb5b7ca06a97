"""A learned critic beside the statistics: can a small CNN tell the real captures from the simulated ones?

A classifier two-sample test. Patches of the calibration pairs are shown to a small CNN as (clean patch, image
patch − clean patch, the image's fine detail, position in the frame), labelled real (the capture) or simulated
(the profile's sample of the same clean image, drawn as training would see it); both come from the same positions,
so content alone tells nothing. The critic is then scored on patches of the held-out pairs, which it never saw:
accuracy 0.5 means the simulation cannot be told from the camera, 1.0 that every patch gives it away. The 95 %
interval comes from a bootstrap over held-out *pairs* (patches of one image are not independent).

Where it decides is reported by the patch's distance from the frame centre, its clean intensity, and whether it is
flat (most of its pixels on :func:`~camdegrade.functional.analysis.flat_mask`) or textured.

With ``image_only=True`` the critic sees only the image's own planes (RGB and its fine detail; no clean patch, no
residual, no position): what a model trained on the simulation sees. The patches, the split and the scoring are
the same.

References:
    D. Lopez-Paz, M. Oquab, "Revisiting Classifier Two-Sample Tests", ICLR 2017.
"""

from __future__ import annotations

import math
import statistics
import threading
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, fields, replace

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from camdegrade._seeds import derive_seed, derived_generator
from camdegrade.functional.analysis import box_mean, flat_mask, gradient_energy

__all__ = [
    "BATCH",
    "BOOTSTRAP_ROUNDS",
    "FLAT_SHARE",
    "GRID",
    "IMAGE_ONLY_PLANES",
    "INTENSITY_EDGES",
    "LEARNING_RATE",
    "PATCH",
    "PATCHES_PER_PAIR",
    "PLANES",
    "RADIUS_EDGES",
    "SPLIT_PASSES",
    "STEPS",
    "CriticNet",
    "CriticResult",
    "CriticSpread",
    "Patches",
    "alternate_scenes",
    "critic_test",
    "logits",
    "repeated_critic_test",
    "score",
    "score_logits",
    "split_critic_test",
    "train_critic",
]

PATCH = 32
GRID = 8
#: Patches drawn from each pair (the same positions for its real and its simulated image).
PATCHES_PER_PAIR = 24
STEPS = 250
BATCH = 32
LEARNING_RATE = 2e-3
BOOTSTRAP_ROUNDS = 1000
#: Group edges of the "where it decides" breakdown.
RADIUS_EDGES = (1 / 3, 2 / 3)
INTENSITY_EDGES = (1 / 3, 2 / 3)
FLAT_SHARE = 0.5
#: Held while a critic's initial weights are drawn from torch's global generator, seeded for it.
_GLOBAL_RNG = threading.Lock()


#: Input planes: clean RGB, residual RGB (image − clean), the image's fine detail RGB (image minus its 3×3
#: mean, where noise and blocking live), and the position (y, x) in the frame.
PLANES = 11
#: Input planes of the image-only critic: the image's RGB and its fine detail RGB.
IMAGE_ONLY_PLANES = 6


class CriticNet(nn.Module):
    """``planes`` input planes (:data:`PLANES`, or :data:`IMAGE_ONLY_PLANES`) → one logit (real vs simulated).
    Inputs are standardised per plane with the training patches' mean and std (:meth:`standardise`), so small
    signals (a few levels of noise) are not drowned by large ones (a tone shift)."""

    def __init__(self, width: int = 12, planes: int = PLANES) -> None:
        super().__init__()
        self.register_buffer("mean", torch.zeros(planes, 1, 1))
        self.register_buffer("std", torch.ones(planes, 1, 1))
        self.features = nn.Sequential(
            nn.Conv2d(planes, width, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(width, 2 * width, 3, stride=2, padding=1),
            nn.ReLU(),
            nn.Conv2d(2 * width, 2 * width, 3, stride=2, padding=1),
            nn.ReLU(),
        )
        self.head = nn.Linear(4 * width, 1)

    def standardise(self, patches: Tensor) -> None:
        """Set the per-plane mean and std from training ``patches``."""
        self.mean.copy_(patches.mean((0, 2, 3))[:, None, None])
        self.std.copy_(patches.std((0, 2, 3)).clamp_min(1e-6)[:, None, None])

    def forward(self, patches: Tensor) -> Tensor:
        hidden = self.features((patches - self.mean) / self.std)
        pooled = torch.cat([hidden.mean((-2, -1)), hidden.pow(2).mean((-2, -1)).sqrt()], 1)  # level and energy
        return self.head(pooled).squeeze(1)


@dataclass
class Patches:
    """Critic inputs ``(M, PLANES or IMAGE_ONLY_PLANES, PATCH, PATCH)``, labels (1 real), the pair each came from,
    and its attributes: where it lies (``top``, ``left`` in pixels, ``radius``) and what its clean patch holds
    (``intensity``, ``flat``, ``texture``: mean gradient energy, ``saturation``: mean of max − min over RGB).
    A position's real and simulated patches share every attribute."""

    inputs: Tensor
    labels: Tensor
    pair: Tensor
    radius: Tensor
    intensity: Tensor
    flat: Tensor
    top: Tensor
    left: Tensor
    texture: Tensor
    saturation: Tensor

    @classmethod
    def sample(
        cls,
        cleans: Sequence[Tensor],
        reals: Sequence[Tensor],
        sims: Sequence[Tensor],
        seed: int,
        stream: str,
        image_only: bool = False,
        features: Sequence[PairFeatures | None] | None = None,
    ) -> Patches:
        """:data:`PATCHES_PER_PAIR` positions of each pair (seeded by ``(seed, stream, index)``); ``features``: the
        pairs' :func:`pair_features`, when the caller computed them once for several samples."""
        features = features if features is not None else [None] * len(cleans)
        parts = [
            _pair_patches(index, clean, real, sim, derived_generator(seed, stream, index), image_only, feature)
            for index, (clean, real, sim, feature) in enumerate(zip(cleans, reals, sims, features, strict=True))
        ]
        parts = [part for part in parts if part is not None]
        if not parts:
            raise ValueError(f"the critic needs pairs of at least {PATCH}x{PATCH} pixels")
        return cls(*(torch.cat(column) for column in zip(*parts, strict=True)))

    def __len__(self) -> int:
        return self.labels.numel()

    @classmethod
    def concat(cls, parts: Sequence[Patches]) -> Patches:
        """The patches of ``parts`` in order, the pairs of each numbered after those of the parts before it."""
        offset, shifted = 0, []
        for part in parts:
            shifted.append(replace(part, pair=part.pair + offset))
            offset += int(part.pair.max()) + 1 if len(part) else 0
        return cls(*(torch.cat([getattr(part, f.name) for part in shifted]) for f in fields(cls)))


@dataclass
class PairFeatures:
    """What the patches of one (clean, real, sim) pair are cut from, whatever their positions: the flat mask, the
    gradient energy and the colourfulness of the clean image, and the fine detail of the real and the simulated
    image (each minus its 3×3 mean)."""

    flat: Tensor
    energy: Tensor
    chroma: Tensor
    detail: dict[float, Tensor]


def pair_features(clean: Tensor, real: Tensor, sim: Tensor) -> PairFeatures:
    """:class:`PairFeatures` of one pair (computed once, they serve every critic that samples it)."""
    return PairFeatures(
        flat=flat_mask(clean).float(),
        energy=gradient_energy(clean),
        chroma=clean.amax(-3) - clean.amin(-3),
        detail={label: image - box_mean(image, 3) for label, image in ((1.0, real), (0.0, sim))},
    )


def _pair_patches(
    index: int,
    clean: Tensor,
    real: Tensor,
    sim: Tensor,
    generator: torch.Generator,
    image_only: bool = False,
    features: PairFeatures | None = None,
) -> tuple[Tensor, ...] | None:
    height, width = clean.shape[-2:]
    if min(height, width) < PATCH:
        return None
    # On the 8-pixel grid: a codec's 8×8 blocks and the network's 4-pixel grid keep one phase in every patch.
    tops = (torch.randint(0, (height - PATCH) // GRID + 1, (PATCHES_PER_PAIR,), generator=generator) * GRID).tolist()
    lefts = (torch.randint(0, (width - PATCH) // GRID + 1, (PATCHES_PER_PAIR,), generator=generator) * GRID).tolist()
    ys = torch.linspace(-1, 1, height)[:, None].expand(height, width)
    xs = torch.linspace(-1, 1, width)[None, :].expand(height, width)
    features = features or pair_features(clean, real, sim)
    flat, energy, chroma, detail = features.flat, features.energy, features.chroma, features.detail
    inputs, labels, radius, intensity, flat_share, texture, saturation = [], [], [], [], [], [], []
    for top, left in zip(tops, lefts, strict=True):
        window = (..., slice(top, top + PATCH), slice(left, left + PATCH))
        position = torch.stack([ys[window], xs[window]])
        for label, image in ((1.0, real), (0.0, sim)):
            if image_only:
                inputs.append(torch.cat([image[window], detail[label][window]]))
            else:
                residual = image[window] - clean[window]
                inputs.append(torch.cat([clean[window], residual, detail[label][window], position]))
            labels.append(label)
        centre_y, centre_x = (top + PATCH / 2) / height - 0.5, (left + PATCH / 2) / width - 0.5
        patch_radius = math.hypot(centre_y, centre_x) / math.hypot(0.5, 0.5)
        patch_intensity = float(clean[window].mean())
        share = float(flat[window].mean())
        radius += [patch_radius] * 2
        intensity += [patch_intensity] * 2
        flat_share += [share] * 2
        texture += [float(energy[window].mean())] * 2
        saturation += [float(chroma[window].mean())] * 2
    count = len(labels)
    return (
        torch.stack(inputs),
        torch.tensor(labels),
        torch.full((count,), index),
        torch.tensor(radius),
        torch.tensor(intensity),
        torch.tensor(flat_share) >= FLAT_SHARE,
        torch.tensor(tops).repeat_interleave(2),
        torch.tensor(lefts).repeat_interleave(2),
        torch.tensor(texture),
        torch.tensor(saturation),
    )


@dataclass
class CriticResult:
    """How well the critic tells held-out real captures from simulations (0.5: not at all)."""

    accuracy: float
    low: float
    high: float
    patches: int
    pairs: int
    seconds: float
    by_position: dict[str, dict[str, float]] = field(default_factory=dict)
    by_intensity: dict[str, dict[str, float]] = field(default_factory=dict)
    by_texture: dict[str, dict[str, float]] = field(default_factory=dict)
    #: Whether it gave the same answer for every held-out patch: it learned nothing that tells them apart, and,
    #: every pair holding as many real as simulated patches, scores exactly 0.5 with an interval of zero width.
    one_answer: bool = False

    @property
    def distinguishable(self) -> bool:
        """Whether the 95 % interval lies above chance."""
        return self.low > 0.5

    def to_dict(self) -> dict:
        out = asdict(self)
        for key in ("accuracy", "low", "high", "seconds"):
            out[key] = round(out[key], 4)
        return out

    def describe(self) -> str:
        text = f"critic accuracy {self.accuracy:.2f} [95 % CI {self.low:.2f}–{self.high:.2f}] on {self.patches} patches"
        return text + (" (the same answer for every patch)" if self.one_answer else "")


def train_critic(patches: Patches, seed: int, steps: int = STEPS) -> CriticNet:
    """The critic fitted to ``patches`` with Adam, minibatches drawn from a seeded generator."""
    with _GLOBAL_RNG, torch.random.fork_rng(devices=[]):  # critics may be trained side by side
        torch.manual_seed(derive_seed(seed, "critic-init"))
        net = CriticNet(planes=patches.inputs.shape[1])
    net.standardise(patches.inputs)
    optimizer = torch.optim.Adam(net.parameters(), lr=LEARNING_RATE)
    generator = derived_generator(seed, "critic-batches")
    net.train()
    for _ in range(steps):
        batch = torch.randint(0, len(patches), (min(BATCH, len(patches)),), generator=generator)
        loss = F.binary_cross_entropy_with_logits(net(patches.inputs[batch]), patches.labels[batch])
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
    return net.eval()


def logits(net: CriticNet, patches: Patches) -> Tensor:
    """``(M,)`` the critic's logit per patch (above 0: it says real)."""
    with torch.no_grad():
        return net(patches.inputs)


def score(net: CriticNet, patches: Patches, seed: int, seconds: float = 0.0) -> CriticResult:
    """Held-out accuracy, its bootstrap interval over pairs, and the breakdown by where the patches lie."""
    return score_logits(logits(net, patches), patches, seed, seconds)


def score_logits(towards_real: Tensor, patches: Patches, seed: int, seconds: float = 0.0) -> CriticResult:
    """:func:`score` from the logits a critic (or several, each on the pairs it never saw) gave ``patches``."""
    answers = (towards_real > 0).float()
    correct = (answers == patches.labels).float()
    pairs = torch.unique(patches.pair)
    per_pair = torch.stack([correct[patches.pair == pair].mean() for pair in pairs])
    weights = torch.stack([(patches.pair == pair).sum() for pair in pairs]).float()
    low, high = _bootstrap_interval(per_pair, weights, seed)
    return CriticResult(
        accuracy=float(correct.mean()),
        low=low,
        high=high,
        patches=len(patches),
        pairs=len(pairs),
        seconds=seconds,
        by_position=_groups(correct, patches.radius, RADIUS_EDGES, ("centre", "middle", "edge")),
        by_intensity=_groups(correct, patches.intensity, INTENSITY_EDGES, ("dark", "mid", "bright")),
        by_texture=_groups(correct, (~patches.flat).float(), (0.5,), ("flat", "textured")),
        one_answer=bool((answers == answers[0]).all()),
    )


def _bootstrap_interval(per_pair: Tensor, weights: Tensor, seed: int) -> tuple[float, float]:
    """The 95 % interval of the patch-weighted mean of ``per_pair`` accuracies, by a bootstrap over the pairs."""
    generator = derived_generator(seed, "critic-bootstrap")
    draws = torch.randint(0, len(per_pair), (BOOTSTRAP_ROUNDS, len(per_pair)), generator=generator)
    resampled = (per_pair[draws] * weights[draws]).sum(1) / weights[draws].sum(1)
    low, high = torch.quantile(resampled, torch.tensor([0.025, 0.975])).tolist()
    return low, high


def _groups(correct: Tensor, value: Tensor, edges: Sequence[float], names: Sequence[str]) -> dict:
    index = torch.bucketize(value, torch.tensor(edges, dtype=value.dtype))
    out = {}
    for group, name in enumerate(names):
        chosen = correct[index == group]
        out[name] = {"accuracy": round(float(chosen.mean()), 4) if chosen.numel() else None, "patches": chosen.numel()}
    return out


def critic_test(
    calibration: tuple[Sequence[Tensor], Sequence[Tensor], Sequence[Tensor]],
    held_out: tuple[Sequence[Tensor], Sequence[Tensor], Sequence[Tensor]],
    seed: int,
    steps: int = STEPS,
    image_only: bool = False,
) -> CriticResult:
    """Train on ``calibration`` = (cleans, reals, sims) and score on ``held_out`` (the same three lists).

    ``image_only``: the critic sees the image alone (the clean images still place the patches and group them
    flat or textured in the report, and never reach the critic)."""
    started = time.perf_counter()
    net = train_critic(Patches.sample(*calibration, seed, "critic-calibration", image_only), seed, steps)
    held = Patches.sample(*held_out, seed, "critic-held-out", image_only)
    return score(net, held, seed, time.perf_counter() - started)


#: :func:`split_critic_test` trains for this many passes over its training patches (at most :data:`STEPS` steps):
#: a fit's few validation scenes give a few hundred patches, which 250 steps would show 40 times over.
SPLIT_PASSES = 25


def split_critic_test(
    pairs: tuple[Sequence[Tensor], Sequence[Tensor], Sequence[Tensor]],
    scenes: Sequence[str],
    seed: int,
    steps: int | None = None,
    image_only: bool = False,
) -> CriticResult:
    """:func:`critic_test` on one set of ``pairs`` = (cleans, reals, sims) with no held-out part of its own (a fit's
    validation pairs): their ``scenes``, in sorted order, alternate between training the critic and scoring it, so
    no scene is on both sides. ``steps``: by default :data:`SPLIT_PASSES` passes over the training patches, at most
    :data:`STEPS`. Few scenes make a noisy critic: read its bootstrap interval.

    Raises:
        ValueError: fewer than two scenes, or no pair of at least :data:`PATCH` pixels on either side.
    """
    _check_scenes(pairs, scenes)
    trains = alternate_scenes(scenes)
    calibration = tuple([item for item, chosen in zip(column, trains, strict=True) if chosen] for column in pairs)
    held_out = tuple([item for item, chosen in zip(column, trains, strict=True) if not chosen] for column in pairs)
    return critic_test(calibration, held_out, seed, steps or _split_steps(calibration[0]), image_only)


def _split_steps(cleans: Sequence[Tensor]) -> int:
    """:data:`SPLIT_PASSES` passes over the patches of the pairs of ``cleans``, at most :data:`STEPS` steps."""
    patches = 2 * PATCHES_PER_PAIR * sum(min(clean.shape[-2:]) >= PATCH for clean in cleans)
    return max(1, min(STEPS, math.ceil(SPLIT_PASSES * patches / BATCH)))


def _check_scenes(pairs: tuple[Sequence[Tensor], ...], scenes: Sequence[str]) -> None:
    names = set(scenes)
    if len(names) < 2 or len(scenes) != len(pairs[0]):
        raise ValueError(
            f"the critic needs pairs of at least two scenes (one side trains it, the other scores it), got "
            f"{len(names)} scene(s) for {len(pairs[0])} pair(s)"
        )


@dataclass
class CriticSpread:
    """Several critics on one set of pairs (:func:`repeated_critic_test`): how well they tell the real captures
    from the simulations, and how much that depends on the critic.

    ``accuracy`` is pooled over every critic's held-out patches; ``low``–``high`` the 95 % interval of it by a
    bootstrap over the pairs (each pair's accuracy averaged over the critics that scored it); ``std`` the standard
    deviation of the critics' own accuracies (``accuracies``, two per seed: one per half of the scenes).
    ``patches``: held-out patches per seed (both halves), ``pairs``: the pairs they come from."""

    accuracy: float
    low: float
    high: float
    std: float
    accuracies: tuple[float, ...]
    patches: int
    pairs: int
    seconds: float

    def to_dict(self, digits: int = 3) -> dict:
        """The numbers, rounded, as a profile's ``quality`` stores them."""
        out = {key: round(getattr(self, key), digits) for key in ("accuracy", "low", "high", "std")}
        return out | {
            "critics": len(self.accuracies),
            "accuracies": [round(value, digits) for value in self.accuracies],
            "patches": self.patches,
            "pairs": self.pairs,
        }

    def describe(self) -> str:
        return (
            f"critic accuracy {self.accuracy:.2f} ± {self.std:.2f} over {len(self.accuracies)} critics "
            f"({min(self.accuracies):.2f}–{max(self.accuracies):.2f}) [95 % CI {self.low:.2f}–{self.high:.2f}] on "
            f"{self.pairs} pairs"
        )


def repeated_critic_test(
    pairs: tuple[Sequence[Tensor], Sequence[Tensor], Sequence[Tensor]],
    scenes: Sequence[str],
    seeds: int,
    steps: int | None = None,
    image_only: bool = False,
) -> CriticSpread:
    """:func:`split_critic_test` repeated: for each seed in ``range(seeds)``, one critic trained on each half of the
    scenes (:func:`alternate_scenes`) and scored on the other half, so every pair is scored ``seeds`` times by
    critics that never saw its scene. One critic either finds what tells a simulation from its camera or does not
    (8 critics of the City100 built-in, image only: 0.70 to 0.83; docs/results.md): the mean and the spread of
    several are the measurement.

    Raises:
        ValueError: fewer than two scenes, ``seeds`` below 1, or no pair of at least :data:`PATCH` pixels on a side.
    """
    _check_scenes(pairs, scenes)
    if isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 1:
        raise ValueError(f"seeds must be a positive integer, got seeds={seeds!r}")
    started = time.perf_counter()
    trains = alternate_scenes(scenes)
    first = [index for index, chosen in enumerate(trains) if chosen]
    second = [index for index, chosen in enumerate(trains) if not chosen]
    correct_sum, count = torch.zeros(len(scenes)), torch.zeros(len(scenes))
    accuracies = []
    features = [pair_features(*pair) if min(pair[0].shape[-2:]) >= PATCH else None for pair in zip(*pairs, strict=True)]
    for seed in range(seeds):
        for fit, held in ((first, second), (second, first)):
            calibration = tuple([column[index] for index in fit] for column in pairs)
            scored = tuple([column[index] for index in held] for column in pairs)
            fit_features, held_features = [features[i] for i in fit], [features[i] for i in held]
            patches_in = Patches.sample(*calibration, seed, "critic-calibration", image_only, fit_features)
            net = train_critic(patches_in, seed, steps or _split_steps(calibration[0]))
            patches = Patches.sample(*scored, seed, "critic-held-out", image_only, held_features)
            correct = ((logits(net, patches) > 0).float() == patches.labels).float()
            accuracies.append(float(correct.mean()))
            owner = torch.tensor(held)[patches.pair]
            correct_sum.index_add_(0, owner, correct)
            count.index_add_(0, owner, torch.ones_like(correct))
    used = count > 0
    low, high = _bootstrap_interval(correct_sum[used] / count[used], count[used], 0)
    return CriticSpread(
        accuracy=float(correct_sum.sum() / count.sum()),
        low=low,
        high=high,
        std=statistics.stdev(accuracies) if len(accuracies) > 1 else 0.0,
        accuracies=tuple(accuracies),
        patches=int(count.sum()) // seeds,
        pairs=int(used.sum()),
        seconds=time.perf_counter() - started,
    )


def alternate_scenes(scenes: Sequence[str]) -> list[bool]:
    """For each pair of ``scenes`` (its scene id), whether it trains a critic (True) or scores it: the scenes in
    sorted order alternate between the two, so no scene is on both sides. With a single scene, the pairs alternate
    instead (its pairs still differ, though less than scenes would)."""
    names = sorted(set(scenes))
    if len(names) < 2:
        return [index % 2 == 0 for index in range(len(scenes))]
    return [names.index(scene) % 2 == 0 for scene in scenes]
