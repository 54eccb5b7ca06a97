"""A learned critic beside the statistics: can a small CNN tell the real captures from the simulated ones?

A classifier two-sample test. Patches of the calibration pairs are shown to a small CNN as (clean patch, image
patch − clean patch, the image's fine detail, position in the frame), labelled real (the capture) or simulated
(the profile's sample of the same clean image, drawn as training would see it); both come from the same positions,
so content alone tells nothing. The critic is then scored on patches of the held-out pairs, which it never saw:
accuracy 0.5 means the simulation cannot be told from the camera, 1.0 that every patch gives it away. The 95 %
interval comes from a bootstrap over held-out *pairs* (patches of one image are not independent).

Where it decides is reported by the patch's distance from the frame centre, its clean intensity, and whether it is
flat (most of its pixels on :func:`~camdegrade.functional.analysis.images.flat_mask`) or textured.

With ``image_only=True`` the critic sees only the image's own planes (RGB and its fine detail; no clean patch, no
residual, no position): what a model trained on the simulation sees. The patches, the split and the scoring are
the same.

References:
    D. Lopez-Paz, M. Oquab, "Revisiting Classifier Two-Sample Tests", ICLR 2017.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from camdegrade._support.seeds import derive_seed, derived_generator
from camdegrade.measures.critic.patches import PLANES, Patches

__all__ = [
    "BATCH",
    "BOOTSTRAP_ROUNDS",
    "INTENSITY_EDGES",
    "LEARNING_RATE",
    "RADIUS_EDGES",
    "STEPS",
    "CriticNet",
    "CriticResult",
    "accuracy_groups",
    "bootstrap_interval",
    "critic_test",
    "logits",
    "score",
    "score_logits",
    "train_critic",
]

STEPS = 250
BATCH = 32
LEARNING_RATE = 2e-3
BOOTSTRAP_ROUNDS = 1000
#: Group edges of the "where it decides" breakdown.
RADIUS_EDGES = (1 / 3, 2 / 3)
INTENSITY_EDGES = (1 / 3, 2 / 3)
#: Held while a critic's initial weights are drawn from torch's global generator, seeded for it.
_GLOBAL_RNG = threading.Lock()


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
    low, high = bootstrap_interval(per_pair, weights, seed)
    return CriticResult(
        accuracy=float(correct.mean()),
        low=low,
        high=high,
        patches=len(patches),
        pairs=len(pairs),
        seconds=seconds,
        by_position=accuracy_groups(correct, patches.radius, RADIUS_EDGES, ("centre", "middle", "edge")),
        by_intensity=accuracy_groups(correct, patches.intensity, INTENSITY_EDGES, ("dark", "mid", "bright")),
        by_texture=accuracy_groups(correct, (~patches.flat).float(), (0.5,), ("flat", "textured")),
        one_answer=bool((answers == answers[0]).all()),
    )


def bootstrap_interval(per_pair: Tensor, weights: Tensor, seed: int) -> tuple[float, float]:
    """The 95 % interval of the patch-weighted mean of ``per_pair`` accuracies, by a bootstrap over the pairs."""
    generator = derived_generator(seed, "critic-bootstrap")
    draws = torch.randint(0, len(per_pair), (BOOTSTRAP_ROUNDS, len(per_pair)), generator=generator)
    resampled = (per_pair[draws] * weights[draws]).sum(1) / weights[draws].sum(1)
    low, high = torch.quantile(resampled, torch.tensor([0.025, 0.975])).tolist()
    return low, high


def accuracy_groups(correct: Tensor, value: Tensor, edges: Sequence[float], names: Sequence[str]) -> dict:
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
