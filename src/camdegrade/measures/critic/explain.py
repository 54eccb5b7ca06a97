"""Why a trained critic decides as it does: the held-out patches it is surest about, and where it is right.

The critic of :mod:`camdegrade.measures.critic` gives one number (its held-out accuracy). To see what gives the
simulation away, :func:`explain_critic` returns

- the patches it is surest about, for each class the ``k`` with the largest logit towards their own class, each
  with the other image's patch at the same position (real beside simulated, same clean content), its pair and its
  position; :func:`render_surest` draws them at 2× nearest-neighbour with labels, and if asked the fine detail
  the critic saw beside them (:func:`surest_png`: PNG bytes);
- its accuracy by group of the clean patch: texture (gradient energy), intensity, colour (saturation: max − min
  over RGB) and position (distance from the frame centre), each split at its terciles over the held-out patches,
  with the patch count of every group.

A position's real and simulated patches share their group (the groups are read from the clean patch), so every
group holds as many real as simulated patches and a critic that answers one class everywhere scores 0.5 in each.
"""

from __future__ import annotations

import io
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import partial

import torch
from PIL import Image, ImageDraw
from torch import Tensor

from camdegrade._runtime.threads import side_by_side
from camdegrade._support.pixels import unit_to_bytes
from camdegrade.measures.critic import (
    IMAGE_ONLY_PLANES,
    PLANES,
    STEPS,
    CriticNet,
    CriticResult,
    Patches,
    logits,
    score,
    score_logits,
    train_critic,
)
from camdegrade.measures.critic.core import accuracy_groups

__all__ = [
    "GROUPINGS",
    "LABELS",
    "TERCILES",
    "CriticExplanation",
    "SurePatch",
    "accuracy_by_group",
    "crossfit_critic_test",
    "explain_critic",
    "explained_critic_test",
    "groups_from_logits",
    "render_surest",
    "surest_from_logits",
    "surest_patches",
    "surest_png",
]

#: The groups of the breakdown: the attribute of :class:`~camdegrade.measures.critic.Patches` each is read from,
#: and the names of its terciles (lowest first).
GROUPINGS = {
    "texture": ("texture", ("flat", "mid", "textured")),
    "intensity": ("intensity", ("dark", "mid", "bright")),
    "colour": ("saturation", ("grey", "mid", "colourful")),
    "position": ("radius", ("centre", "middle", "edge")),
}
TERCILES = (1 / 3, 2 / 3)
LABELS = {1.0: "real", 0.0: "simulated"}


@dataclass(frozen=True)
class SurePatch:
    """One held-out patch the critic is sure about, beside the other image's patch at the same position.

    ``label`` is the patch's true class; ``margin`` the critic's logit towards that class (its probability of the
    class is ``sigmoid(margin)``, which rounds to 1 while the margins still rank the patches). ``real`` and
    ``simulated`` are ``(3, PATCH, PATCH)`` float images in [0, 1] of the same clean content; ``real_detail`` and
    ``simulated_detail`` the fine-detail planes the critic was given for them (image minus its 3×3 mean)."""

    label: str
    margin: float
    pair: int
    top: int
    left: int
    real: Tensor
    simulated: Tensor
    real_detail: Tensor
    simulated_detail: Tensor

    @property
    def probability(self) -> float:
        """The critic's probability of the patch's true class."""
        odds = math.exp(-abs(self.margin))  # never overflows
        return 1.0 / (1.0 + odds) if self.margin >= 0 else odds / (1.0 + odds)

    def caption(self, names: Sequence[str] | None = None) -> str:
        """``<pair> y<top> x<left>`` and the probability, or the margin once the probability rounds to 1."""
        where = names[self.pair] if names is not None else f"pair {self.pair}"
        sure = f"p {self.probability:.3f}" if self.probability < 0.9995 else f"logit {self.margin:.1f}"
        return f"{where} y{self.top} x{self.left} {sure}"


@dataclass
class CriticExplanation:
    """The surest patches (real first, then simulated, surest first) and the accuracy by group."""

    surest: list[SurePatch]
    groups: dict[str, dict[str, dict]] = field(default_factory=dict)
    #: The tercile edges of each grouping's attribute over the held-out patches.
    edges: dict[str, tuple[float, float]] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "surest": [
                {"label": p.label, "margin": round(p.margin, 3), "pair": p.pair, "top": p.top, "left": p.left}
                for p in self.surest
            ],
            "groups": self.groups,
            "edges": {key: [round(value, 6) for value in pair] for key, pair in self.edges.items()},
        }

    def table(self) -> str:
        """The accuracy by group as a markdown table (one row per grouping; ``accuracy (patches)`` per tercile)."""
        lines = ["| grouping | low tercile | mid tercile | high tercile |", "|---|---|---|---|"]
        for grouping, groups in self.groups.items():
            cells = [
                f"{name} {_accuracy_text(value['accuracy'])} ({value['patches']})" for name, value in groups.items()
            ]
            lines.append(f"| {grouping} | " + " | ".join(cells) + " |")
        return "\n".join(lines)


def _accuracy_text(accuracy: float | None) -> str:
    return "n/a" if accuracy is None else f"{accuracy:.3f}"


def surest_patches(net: CriticNet, patches: Patches, k: int, per_pair: int | None = None) -> list[SurePatch]:
    """For each class (real, then simulated), the ``k`` patches with the largest logit towards their own class
    (fewer when the class has fewer), surest first; at most ``per_pair`` of each class from one pair (``None``:
    no limit), so that one easy image does not fill the list."""
    _check(net, patches)
    return surest_from_logits(logits(net, patches), patches, k, per_pair)


def surest_from_logits(towards_real: Tensor, patches: Patches, k: int, per_pair: int | None = None) -> list[SurePatch]:
    """:func:`surest_patches` from the logits a critic (or several, each on pairs it never saw) gave ``patches``."""
    k = _positive_int(k, "k")
    per_pair = None if per_pair is None else _positive_int(per_pair, "per_pair")
    partner = _partners(patches)
    images, details = _planes(patches.inputs)
    out = []
    for label in (1.0, 0.0):
        chosen = (patches.labels == label).nonzero().squeeze(1)
        margins = towards_real[chosen] if label == 1.0 else -towards_real[chosen]
        order = torch.sort(margins, descending=True, stable=True).indices
        for index, margin in _limited(chosen[order].tolist(), margins[order].tolist(), patches.pair, k, per_pair):
            real, simulated = (index, partner[index]) if label == 1.0 else (partner[index], index)
            where = (int(patches.pair[index]), int(patches.top[index]), int(patches.left[index]))
            pictures = (images[real], images[simulated], details[real], details[simulated])
            out.append(SurePatch(LABELS[label], margin, *where, *pictures))
    return out


def _limited(
    indices: list[int], margins: list[float], pair: Tensor, k: int, per_pair: int | None
) -> list[tuple[int, float]]:
    """The first ``k`` of ``indices`` (with their margins) taking at most ``per_pair`` from any one pair."""
    taken: dict[int, int] = {}
    out = []
    for index, margin in zip(indices, margins, strict=True):
        owner = int(pair[index])
        if per_pair is not None and taken.get(owner, 0) >= per_pair:
            continue
        taken[owner] = taken.get(owner, 0) + 1
        out.append((index, margin))
        if len(out) == k:
            break
    return out


def accuracy_by_group(net: CriticNet, patches: Patches) -> tuple[dict[str, dict[str, dict]], dict]:
    """The critic's accuracy and patch count per tercile of texture, intensity, colour and position, and the
    tercile edges."""
    _check(net, patches)
    return groups_from_logits(logits(net, patches), patches)


def groups_from_logits(towards_real: Tensor, patches: Patches) -> tuple[dict[str, dict[str, dict]], dict]:
    """:func:`accuracy_by_group` from the logits a critic (or several) gave ``patches``."""
    correct = ((towards_real > 0).float() == patches.labels).float()
    groups, edges = {}, {}
    for grouping, (attribute, names) in GROUPINGS.items():
        value = getattr(patches, attribute).float()
        cut = torch.quantile(value, torch.tensor(TERCILES, dtype=value.dtype))
        groups[grouping] = accuracy_groups(correct, value, cut.tolist(), names)
        edges[grouping] = tuple(cut.tolist())
    return groups, edges


def explain_critic(net: CriticNet, patches: Patches, k: int = 6, per_pair: int | None = None) -> CriticExplanation:
    """The ``k`` surest patches of each class (at most ``per_pair`` from one pair) and the accuracy by group (see
    the module's docstring)."""
    groups, edges = accuracy_by_group(net, patches)
    return CriticExplanation(surest_patches(net, patches, k, per_pair), groups, edges)


def explained_critic_test(
    calibration: tuple[Sequence[Tensor], Sequence[Tensor], Sequence[Tensor]],
    held_out: tuple[Sequence[Tensor], Sequence[Tensor], Sequence[Tensor]],
    seed: int,
    steps: int = STEPS,
    image_only: bool = False,
    k: int = 6,
    per_pair: int | None = None,
) -> tuple[CriticResult, CriticExplanation]:
    """:func:`~camdegrade.measures.critic.core.critic_test` (the same patches, critic and score for the same seed) and
    the explanation of the critic it trained."""
    started = time.perf_counter()
    net = train_critic(Patches.sample(*calibration, seed, "critic-calibration", image_only), seed, steps)
    held = Patches.sample(*held_out, seed, "critic-held-out", image_only)
    return score(net, held, seed, time.perf_counter() - started), explain_critic(net, held, k, per_pair)


def crossfit_critic_test(
    pairs: tuple[Sequence[Tensor], Sequence[Tensor], Sequence[Tensor]],
    trains: Sequence[bool],
    seed: int,
    steps: int = STEPS,
    k: int = 6,
    per_pair: int | None = None,
    image_only: bool = False,
) -> tuple[CriticResult, CriticExplanation, tuple[float, float]]:
    """A two-fold critic on one set of ``pairs`` = (cleans, reals, sims): a critic trained on the pairs ``trains``
    marks scores the others, a second trained on those others scores the first, so every pair is scored by a critic
    that never saw it. With ``image_only`` the critics see the image alone, not the clean source beside it.
    Returns the pooled score (its interval a bootstrap over all the pairs), the explanation of the pooled logits,
    and each fold's accuracy (how much the critic depends on which pairs trained it).

    References:
        D. Lopez-Paz, M. Oquab, "Revisiting Classifier Two-Sample Tests", ICLR 2017.
    """
    if len(trains) != len(pairs[0]) or all(trains) or not any(trains):
        raise ValueError(
            f"trains must mark some but not all of the {len(pairs[0])} pairs, got {sum(map(bool, trains))} of "
            f"{len(trains)}"
        )
    started = time.perf_counter()
    scored = side_by_side([partial(_fold, pairs, trains, side, seed, steps, image_only) for side in (True, False)])
    folds = [float(((towards_real > 0).float() == patches.labels).float().mean()) for patches, towards_real in scored]
    patches, towards_real = (
        Patches.concat([p for p, _ in scored]),
        torch.cat([fold_logits for _, fold_logits in scored]),
    )
    result = score_logits(towards_real, patches, seed, time.perf_counter() - started)
    groups, edges = groups_from_logits(towards_real, patches)
    explanation = CriticExplanation(surest_from_logits(towards_real, patches, k, per_pair), groups, edges)
    return result, explanation, (folds[0], folds[1])


def _fold(
    pairs: tuple[Sequence[Tensor], Sequence[Tensor], Sequence[Tensor]],
    trains: Sequence[bool],
    side: bool,
    seed: int,
    steps: int,
    image_only: bool,
) -> tuple[Patches, Tensor]:
    """One fold: a critic trained on the pairs ``trains`` marks ``side``, and its logits on the others' patches."""
    train = tuple([item for item, t in zip(column, trains, strict=True) if bool(t) is side] for column in pairs)
    held = tuple([item for item, t in zip(column, trains, strict=True) if bool(t) is not side] for column in pairs)
    net = train_critic(Patches.sample(*train, seed, "critic-calibration", image_only), seed, steps)
    patches = Patches.sample(*held, seed, "critic-held-out", image_only)
    return patches, logits(net, patches)


def render_surest(
    surest: Sequence[SurePatch],
    scale: int = 2,
    names: Sequence[str] | None = None,
    title: str | None = None,
    detail_gain: float | None = None,
) -> Image.Image:
    """The surest patches as an RGB image: one row per patch, real beside simulated at ``scale``× nearest-neighbour,
    captioned with the pair (or ``names[pair]``), the position and the critic's certainty; the patches it is
    surest are real, in the left column, and simulated, in the right one; ``title`` (one or more lines) above.
    With ``detail_gain``, each row goes on with the fine detail the critic saw, real then simulated, as
    ``0.5 + detail_gain · detail`` (grey is none)."""
    scale = _positive_int(scale, "scale")
    if not surest:
        raise ValueError("surest must hold at least one SurePatch, got none")
    if detail_gain is not None and not (isinstance(detail_gain, int | float) and detail_gain > 0):
        raise ValueError(f"detail_gain must be a positive number or None, got detail_gain={detail_gain!r}")
    side = surest[0].real.shape[-1] * scale
    caption, gap, margin = 12, 4, 4
    tiles = 2 if detail_gain is None else 4
    columns = [[p for p in surest if p.label == label] for label in ("real", "simulated")]
    block = max(tiles * (side + gap), 190)
    rows = max(len(column) for column in columns)
    lines = title.splitlines() if title else []
    header = margin + (len(lines) + 1) * caption + margin
    canvas = Image.new("RGB", (2 * block + 4 * margin, header + rows * (side + caption + gap)), "white")
    draw = ImageDraw.Draw(canvas)
    for number, line in enumerate(lines):
        draw.text((margin, margin + number * caption), line, fill="black")
    heading = "real | simulated" + ("" if detail_gain is None else f" | their detail x{detail_gain:g}")
    for number, (label, column) in enumerate(zip(("real", "simulated"), columns, strict=True)):
        x = margin + number * (block + 2 * margin)
        draw.text((x, header - caption - margin), f"surest {label}: {heading}", fill="black")
        for row, patch in enumerate(column):
            y = header + row * (side + caption + gap)
            draw.text((x, y), patch.caption(names), fill="black")
            pictures = [patch.real, patch.simulated]
            if detail_gain is not None:
                pictures += [0.5 + detail_gain * patch.real_detail, 0.5 + detail_gain * patch.simulated_detail]
            for tile, picture in enumerate(pictures):
                canvas.paste(_zoomed(picture, scale), (x + tile * (side + gap), y + caption))
    return canvas


def surest_png(
    surest: Sequence[SurePatch],
    scale: int = 2,
    names: Sequence[str] | None = None,
    title: str | None = None,
    detail_gain: float | None = None,
) -> bytes:
    """:func:`render_surest` as PNG bytes (the same patches give the same bytes)."""
    buffer = io.BytesIO()
    render_surest(surest, scale, names, title, detail_gain).save(buffer, format="PNG")
    return buffer.getvalue()


def _zoomed(image: Tensor, scale: int) -> Image.Image:
    picture = Image.fromarray(unit_to_bytes(image.clamp(0, 1)).permute(1, 2, 0).numpy())
    return picture.resize((picture.width * scale, picture.height * scale), Image.NEAREST)


def _planes(inputs: Tensor) -> tuple[Tensor, Tensor]:
    """The image RGB and the fine-detail RGB of each patch: planes 0–2 and 3–5 of an image-only critic's input;
    clean + residual (0–2 + 3–5) and 6–8 of a paired one."""
    if inputs.shape[1] == IMAGE_ONLY_PLANES:
        return inputs[:, :3], inputs[:, 3:6]
    return inputs[:, :3] + inputs[:, 3:6], inputs[:, 6:9]


def _partners(patches: Patches) -> list[int]:
    """For every patch, the index of the other class's patch at the same pair and position."""
    keys = list(zip(patches.pair.tolist(), patches.top.tolist(), patches.left.tolist(), strict=True))
    labels = patches.labels.tolist()
    where = {(key, label): index for index, (key, label) in enumerate(zip(keys, labels, strict=True))}
    return [where[(key, 1.0 - label)] for key, label in zip(keys, labels, strict=True)]


def _check(net: CriticNet, patches: Patches) -> None:
    if not isinstance(net, CriticNet):
        raise TypeError(f"net must be a CriticNet (from train_critic), got {type(net).__name__}")
    if not isinstance(patches, Patches):
        raise TypeError(f"patches must be a critic Patches (from Patches.sample), got {type(patches).__name__}")
    planes = net.mean.shape[0]
    if patches.inputs.shape[1] != planes or planes not in (PLANES, IMAGE_ONLY_PLANES):
        raise ValueError(
            f"patches must have the {planes} planes the critic was trained on, got {patches.inputs.shape[1]}"
        )


def _positive_int(value: object, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"{name} must be a positive integer, got {type(value).__name__} {value!r}")
    if value < 1:
        raise ValueError(f"{name} must be a positive integer, got {name}={value}")
    return value
