"""The network's output curve refitted with every stage after it in place, on whole frames.

A paired fit trains its network on random windows through the sensor stage alone, then fits the stages it keeps
after the network one by one on the network's output. A stage whose own fit solves for a tone it then drops leaves
the chain's tone wrong: a vignetting stage is fitted as ``capture ≈ c · output · falloff`` with a free exposure
``c`` that it does not keep, while the network had already learned the vignetted frames' mean tone (weighted to the
frame's centre, which random windows cover most often). On the foreign webcam of ``tests/foreign_cameras``
(cos⁴ vignetting) the network through its sensor was right on the windows it trained on (within 1.4 levels per tenth
of the clean value), 5 levels too bright over whole frames, and, with the vignetting stage after it, 4.6 levels too
dark (8 in the highlights). Refitting the network's per-channel output curve (:class:`~camdegrade.network.
LocalAffineNet` with ``curves``) by least squares through the deterministic chain (every stage's
:meth:`~camdegrade.effects.Effect.without_randomness` centre, the conditional mean every stage is fitted against) on
whole frames gives the chain the captures' tone; the stages, the network's filter and its colour field are kept.

References:
    D. C. Liu, J. Nocedal, "On the limited memory BFGS method for large scale optimization", Mathematical
    Programming 45, 1989 (the optimizer: ``torch.optim.LBFGS`` with a strong-Wolfe line search).
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import torch
from torch import Tensor

from camdegrade._support.seeds import derived_generator
from camdegrade.effects import Effect
from camdegrade.effects.base import evenly_spaced
from camdegrade.effects.chain import apply_stages
from camdegrade.network import ShiftNetwork
from camdegrade.network.inference import run_network
from camdegrade.network.nets import piecewise_linear
from camdegrade.pairs.pairset import ImagePair

__all__ = [
    "CurveInputs",
    "chain_error",
    "curve_inputs",
    "has_output_curve",
    "refit_output_curve",
    "refit_pairs",
    "with_output_curve",
]

#: L-BFGS iterations of the refit (the error is smooth in the curve's 3 × 17 knots): on the webcam a second run of
#: 40 from where the first stopped changed nothing.
ITERATIONS = 40

#: The refit reads whole frames of at most this many pixels in all (evenly spaced pairs, at least one): 32 frames of
#: 128² took 10 CPU-s on one core (the webcam). On City100 (840 × 600) two frames overfit their scenes' tone (the
#: curve refitted alone: validation error +9.1 %), eight did not (+0.55 %; the judge's two refits about 17 CPU-s).
PIXEL_BUDGET = 1 << 22

#: What the output curve reads for each pair (float32 ``(1, 3, H, W)`` in [0, 1]), and the pair's capture.
CurveInputs = list[tuple[Tensor, Tensor]]


def has_output_curve(network: ShiftNetwork | None) -> bool:
    """Whether ``network`` ends in a learned per-channel curve (``LocalAffineNet(curves=True)``)."""
    return network is not None and bool(getattr(network, "curves", False))


def with_output_curve(network: ShiftNetwork, knots: Tensor) -> ShiftNetwork:
    """A copy of ``network`` whose output curve passes through ``knots`` ``(3, K)``."""
    copied = copy.deepcopy(network)
    with torch.no_grad():
        copied.curve[1].copy_(knots)
    return copied


def refit_pairs(pairs: Sequence[ImagePair], most: int) -> list[ImagePair]:
    """At most ``most`` of ``pairs``, evenly spaced, and no more than :data:`PIXEL_BUDGET` pixels of captures in all
    (at least one pair)."""
    pixels = max(1, max((captured[0].numel() for _, captured in pairs), default=1))
    return evenly_spaced(list(pairs), max(1, min(most, PIXEL_BUDGET // pixels)))


def curve_inputs(network: ShiftNetwork, pairs: Sequence[ImagePair]) -> CurveInputs:
    """For each ``(clean, capture)`` pair (float in [0, 1]), what ``network``'s output curve reads: its output with
    that curve the identity. The curve takes its end values outside [0, 1], so the curve of this clamped input is the
    network's output."""
    identity = torch.linspace(0.0, 1.0, network.curve.shape[-1]).repeat(3, 1)
    passing = with_output_curve(network, identity)
    with torch.no_grad():
        return [(run_network(passing, clean[None]), captured[None]) for clean, captured in pairs]


def _chain(inputs: Tensor, knots: Tensor, stages: Sequence[Effect], index: int) -> Tensor:
    """The deterministic ``stages`` on the curve of ``inputs`` (image ``index`` of the set, for its draws)."""
    output = piecewise_linear(inputs, knots).clamp(0.0, 1.0)
    generator = derived_generator(0, "chain-tone", index)
    params = [stage.make_params(tuple(output.shape), generator) for stage in stages]
    return apply_stages(stages, params, output).clamp(0.0, 1.0)


def _squared_error(inputs: CurveInputs, knots: Tensor, stages: Sequence[Effect]) -> Tensor:
    """The mean squared error of the chain against the captures over every pixel of ``inputs``."""
    total = sum(
        (_chain(source, knots, stages, index) - captured).pow(2).sum()
        for index, (source, captured) in enumerate(inputs)
    )
    return total / sum(captured.numel() for _, captured in inputs)


def chain_error(inputs: CurveInputs, knots: Tensor, stages: Sequence[Effect]) -> float:
    """:func:`_squared_error` without a graph, as a float."""
    with torch.no_grad():
        return float(_squared_error(inputs, knots, stages))


def refit_output_curve(knots: Tensor, inputs: CurveInputs, stages: Sequence[Effect]) -> Tensor:
    """The output curve's knots ``(3, K)``, started from ``knots``, that minimise :func:`chain_error` (L-BFGS with a
    strong-Wolfe line search, deterministic on one machine). ``ValueError`` where no gradient reaches the knots
    through ``stages`` (a stage that does not build a graph)."""
    fitted = knots.detach().clone().requires_grad_(True)
    optimizer = torch.optim.LBFGS([fitted], lr=1.0, max_iter=ITERATIONS, history_size=20, line_search_fn="strong_wolfe")

    def closure() -> Tensor:
        optimizer.zero_grad()
        loss = _squared_error(inputs, fitted, stages)
        if not loss.requires_grad:
            raise ValueError("no gradient reaches the network's output curve through the stages after it")
        loss.backward()
        return loss

    with torch.enable_grad():
        optimizer.step(closure)
    return fitted.detach()
