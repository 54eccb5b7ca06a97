"""Sensor stage: camera noise (level by intensity, spatial and chroma correlation, banding) and its estimator."""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Literal

import torch
from torch import Tensor

from camdegrade._support.checks import check_non_negative
from camdegrade._support.gaussian_fields import standard_normal
from camdegrade.effects._common import batch_shape, resolve_params, vector
from camdegrade.effects.base import Effect, Encoding, Pairs, check_range, register_effect
from camdegrade.effects.sensor._noise_fit import calibrate, fit_noise, flat_noise_sums
from camdegrade.functional import linear_to_srgb, srgb_to_linear
from camdegrade.functional.sensor.noise import add_noise_, correlated_field, mix_channels, noise_std

__all__ = ["Noise"]


@register_effect
class Noise(Effect):
    """Camera noise added to each pixel: ``x' = clip(x + std(x) · field + row_sigma · z_row + column_sigma · z_col)``.

    ``x`` is the intensity in linear light (``linear=True``: physical sensor noise) or the sRGB value
    (``linear=False``: noise as a camera's processed output holds it, after demosaicking, denoising and tone
    mapping, which is what :meth:`fit` returns). Per channel:

    - ``std(x)² = a·x + b + levels(x)²``: a Poisson–Gaussian line (``a`` shot-noise gain, ``b`` read-noise
      variance) plus an optional table ``levels`` ``(3, K)``, the std at ``K`` knots ``(k + ½)/K`` of ``x``,
      piecewise linear between them and constant beyond;
    - ``field``: unit-variance noise. White (independent pixels and channels) by default; with taps ``across`` and
      ``down`` ``(3, T)`` each channel is filtered separably (autocorrelation ``Σ kᵢ kᵢ₊d`` at lag ``d``), and
      ``mixing`` ``(3, 3)`` correlates the channels (``mixing @ mixing.T`` is their correlation);
    - ``z_row`` ``(3, H, 1)``, ``z_col`` ``(3, 1, W)``: per-row and per-column offsets (banding).

    Args:
        a, b, row_sigma: per channel (scalar or ``(3,)``), non-negative. Neutral 0.
        column_sigma: per-channel column banding; ``None`` (default) has none.
        levels: ``(3, K)`` non-negative std table (units of ``x``); ``None`` has none.
        across, down: ``(3, T)`` taps (odd ``T``), normalised to unit L2 norm per channel; ``None``: white noise.
        mixing: ``(3, 3)``, rows normalised to unit norm; ``None``: independent channels.
        linear: add the noise in linear light (default) rather than to sRGB values.
        gain_jitter: standard deviation of a per-sample log gain ``g`` (ISO variation between shots): ``a·g``,
            ``b·g²`` and every std term times ``g``. 0 disables it.

    ``make_params`` draws every standard normal the forward pass uses, so a seeded generator replays a capture
    byte for byte. A profile records the table size, the number of taps and whether there are columns and a
    mixing matrix in its config; profiles written before these existed load as white noise.

    References:
        A. Foi, M. Trimeche, V. Katkovnik, K. Egiazarian, "Practical Poissonian-Gaussian noise modeling and fitting
        for single-image raw-data", IEEE Transactions on Image Processing 17(10), 2008.
    """

    name = "noise"
    stage = "sensor"
    explains = ("noise", "noise_correlation", "banding")
    a: Tensor
    b: Tensor
    row_sigma: Tensor

    def __init__(
        self,
        a: float | Tensor = 0.0,
        b: float | Tensor = 0.0,
        row_sigma: float | Tensor = 0.0,
        *,
        column_sigma: float | Tensor | None = None,
        levels: Tensor | None = None,
        across: Tensor | None = None,
        down: Tensor | None = None,
        mixing: Tensor | None = None,
        linear: bool = True,
        gain_jitter: float = 0.0,
    ) -> None:
        super().__init__()
        for key, value in (("a", a), ("b", b), ("row_sigma", row_sigma)):
            self.register_buffer(key, _non_negative(vector(value, 3, key), key))
        if column_sigma is not None:
            self.register_buffer("column_sigma", _non_negative(vector(column_sigma, 3, "column_sigma"), "column_sigma"))
        if levels is not None:
            self.register_buffer("levels", _non_negative(_matrix(levels, "levels"), "levels"))
        if (across is None) != (down is None):
            raise ValueError("across and down must be given together (the taps along x and along y), got one of them")
        if across is not None and down is not None:
            self.register_buffer("across", _unit_rows(_taps(across, "across"), "across"))
            self.register_buffer("down", _unit_rows(_taps(down, "down"), "down"))
            if self.across.shape != self.down.shape:
                raise ValueError(
                    f"across and down must have the same shape, got {tuple(self.across.shape)} and "
                    f"{tuple(self.down.shape)}"
                )
        if mixing is not None:
            matrix = torch.as_tensor(mixing, dtype=torch.float32)
            if matrix.shape != (3, 3):
                raise ValueError(f"mixing must have shape (3, 3), got shape {tuple(matrix.shape)}")
            self.register_buffer("mixing", _unit_rows(matrix, "mixing"))
        self.linear = bool(linear)
        self.gain_jitter = check_non_negative(gain_jitter, "gain_jitter")

    # -- structure -------------------------------------------------------------------------------------------------

    @property
    def taps(self) -> int:
        """Taps of the spatial kernel (0: white noise)."""
        return int(self.across.shape[-1]) if hasattr(self, "across") else 0

    @property
    def knots(self) -> int:
        """Knots of the level table (0: none)."""
        return int(self.levels.shape[-1]) if hasattr(self, "levels") else 0

    def config(self) -> dict[str, Any]:
        config: dict[str, Any] = {"linear": self.linear, "gain_jitter": self.gain_jitter}
        if self.knots:
            config["knots"] = self.knots
        if self.taps:
            config["taps"] = self.taps
        if hasattr(self, "column_sigma"):
            config["columns"] = True
        if hasattr(self, "mixing"):
            config["mixing"] = True
        return config

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> Noise:
        """A stage with buffers of the shapes ``config`` describes (values to be loaded from a state dict)."""
        options = dict(config)
        knots, taps = (_count(options.pop(key, 0), key) for key in ("knots", "taps"))
        if not (0 <= knots <= cls.MAX_KNOTS and 0 <= taps <= cls.MAX_TAPS):
            raise ValueError(
                f"knots must be from 0 to {cls.MAX_KNOTS} and taps from 0 to {cls.MAX_TAPS}, got knots={knots}, "
                f"taps={taps}"
            )
        columns, mixing = (_flag(options.pop(key, False), key) for key in ("columns", "mixing"))
        impulse = torch.zeros(3, taps)
        if taps:
            impulse[:, taps // 2] = 1.0
        return cls(
            column_sigma=torch.zeros(3) if columns else None,
            levels=torch.zeros(3, knots) if knots else None,
            across=impulse if taps else None,
            down=impulse.clone() if taps else None,
            mixing=torch.eye(3) if mixing else None,
            **options,
        )

    #: Upper bounds of the stored values: a variance or std above 1 means nothing on [0, 1] images, and a log-gain
    #: std above 2 draws gains whose square overflows.
    MAX_LEVEL = 1.0
    MAX_GAIN_JITTER = 2.0
    #: The most knots and taps a profile may declare (bounded before anything is allocated).
    MAX_KNOTS = 64
    MAX_TAPS = 31

    def check_values(self) -> None:
        super().check_values()
        for key in ("a", "b", "row_sigma", "column_sigma", "levels"):
            if hasattr(self, key):
                check_range(key, getattr(self, key), 0.0, self.MAX_LEVEL)
        check_range("gain_jitter", self.gain_jitter, 0.0, self.MAX_GAIN_JITTER)
        for key in ("across", "down", "mixing"):
            if hasattr(self, key):
                norms = getattr(self, key).double().norm(dim=1)
                if not bool(torch.allclose(norms, torch.ones_like(norms), atol=1e-3)):
                    raise ValueError(f"every row of {key} must have unit norm, got norms {norms.tolist()}")

    def without_randomness(self) -> None:
        """None: the stage only adds zero-mean noise, so the conditional mean leaves it out."""
        return None

    def simplified(self) -> list[Effect]:
        """This stage without its row and column banding (when it has some)."""
        banded = bool((self.row_sigma > 0).any()) or bool((getattr(self, "column_sigma", torch.zeros(1)) > 0).any())
        if not banded:
            return []
        unbanded = copy.deepcopy(self)
        with torch.no_grad():
            unbanded.row_sigma.zero_()
            if hasattr(unbanded, "column_sigma"):
                unbanded.column_sigma.zero_()
        return [unbanded]

    def scaled(self, strength: float) -> Noise:
        """A copy whose noise power is ``strength`` times this one's: ``a`` and ``b`` times ``strength``, every std
        (the level table, row and column banding) times its square root; correlations unchanged."""
        out = copy.deepcopy(self)
        root = math.sqrt(max(strength, 0.0))
        with torch.no_grad():
            for key in ("a", "b"):
                getattr(out, key).mul_(max(strength, 0.0))
            for key in ("levels", "row_sigma", "column_sigma"):
                if hasattr(out, key):
                    getattr(out, key).mul_(root)
        return out

    # -- drawing and applying ----------------------------------------------------------------------------------------

    def make_params(
        self, shape: torch.Size | tuple[int, ...], generator: torch.Generator | None = None
    ) -> dict[str, Tensor]:
        n, channels, height, width = batch_shape(shape)
        margin = 2 * (self.taps // 2)  # a full kernel behind every pixel, up to the frame's edge
        params = {
            "normal": standard_normal((n, channels, height + margin, width + margin), generator),
            "row_normal": torch.randn(n, channels, height, 1, generator=generator),
        }
        if self.gain_jitter > 0:
            params["gain"] = torch.exp(torch.randn(n, generator=generator) * self.gain_jitter)
        if hasattr(self, "column_sigma"):
            params["column_normal"] = torch.randn(n, channels, 1, width, generator=generator)
        return params

    def _banded(self, key: str) -> bool:
        return hasattr(self, key) and bool((getattr(self, key) > 0).any())

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        x = srgb_to_linear(image) if self.linear else image.clone()
        noisy = self.forward_encoded(x, params) if not x.requires_grad else self._add(x, params, in_place=False)
        return linear_to_srgb(noisy) if self.linear else noisy

    def encodings(self) -> tuple[Encoding, Encoding]:
        return ("linear", "linear") if self.linear else ("srgb", "srgb")

    def forward_encoded(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        return self._add(image, params, in_place=True)

    def _add(self, x: Tensor, params: Mapping[str, Tensor] | None, *, in_place: bool) -> Tensor:
        drawn = resolve_params(self, x, params)
        terms = self._terms(x, drawn)
        std = noise_std(x, terms["a"], terms["b"], terms.get("levels"))
        field = self._field(drawn["normal"], x.dtype)
        # Lines without banding cost no pass over the image (their normals are drawn all the same, so that a seed
        # gives the same stream whatever the banding).
        rows = drawn["row_normal"] if self._banded("row_sigma") else None
        columns = drawn.get("column_normal") if self._banded("column_sigma") else None
        if in_place:
            return add_noise_(x, std, field, terms["row_sigma"], rows, terms.get("column_sigma"), columns)
        noisy = x + std * field
        if rows is not None:
            noisy = noisy + rows * terms["row_sigma"]
        if columns is not None:
            noisy = noisy + columns * terms["column_sigma"]
        return noisy.clamp(0.0, 1.0)

    def _terms(self, x: Tensor, drawn: Mapping[str, Tensor]) -> dict[str, Tensor]:
        """This capture's ``a``, ``b`` and std terms on ``x``'s device, shaped to broadcast over ``x`` (per sample
        where an ISO gain was drawn)."""
        gain = drawn["gain"].to(x.dtype) if "gain" in drawn else None
        terms = {}
        for key in ("a", "b", "row_sigma", "column_sigma", "levels"):
            if not hasattr(self, key):
                continue
            value = getattr(self, key).to(x.device, x.dtype)
            if gain is not None:
                power = 2 if key == "b" else 1
                value = value * gain.view(-1, *([1] * value.ndim)) ** power
            terms[key] = value if key == "levels" else value[..., None, None]
        return terms

    def _field(self, normal: Tensor, dtype: torch.dtype) -> Tensor:
        normal = normal.to(dtype)
        mixing = getattr(self, "mixing", None)
        if self.taps:
            return correlated_field(normal, self.across, self.down, mixing)
        if mixing is not None:
            return mix_channels(normal, mixing)
        return normal

    # -- fitting -----------------------------------------------------------------------------------------------------

    @classmethod
    def fit(
        cls,
        source: Pairs,
        target: Pairs,
        *,
        estimator: Literal["excess", "residual"] = "excess",
        taps: int = 5,
        banding: bool = True,
        rounds: int = 2,
        seed: int = 0,
    ) -> Noise:
        """The noise that, added to ``source``, reproduces ``target``'s noise where the source is flat.

        Measured only on pixels where the source is flat in absolute terms
        (:func:`~camdegrade.functional.analysis.images.flat_mask`), never on edges or texture, where a model's misfit
        would read as noise; per channel and intensity bin, with spatial (lags 1, 2) and channel correlation and
        row/column line means (:class:`~camdegrade.functional.analysis.noise.NoiseSums`). Then, starting from the
        closed-form estimate, ``rounds`` rounds of simulated moments: the source plus the fitted noise is simulated
        (seeded), measured the same way, and the level table, correlation targets and banding are corrected by the
        difference to the target (the local-mean bias, clipping and rounding are absorbed this way).

        Args:
            estimator: ``"excess"``, the variance the noise must *add* to the source (``Var target − Var source``):
                right when the source is a model's prediction that already carries texture or noise of its own (a
                profile's deterministic output). ``"residual"``, the variance of ``target − source``: right when the
                source is a noise-free reference of the same frame (the mean of many exposures).
            taps: taps of the fitted spatial kernel (odd; 1 fits white noise).
            banding: fit row and column banding where the data show more than the fitted noise leaves in line
                means (beyond 3 standard errors and 25 % of that null); otherwise none is fitted.
            rounds: simulated-moments rounds.
            seed: seeds the simulations.

        Returns:
            A stage with ``linear=False``: a level table (8 knots), the kernel, a channel mixing matrix, and row and
            column banding (zero where not kept).

        Raises:
            ValueError: a channel has no intensity bin with enough flat pixels (500,
                ``_noise_fit.FIT_MIN_PIXELS``); the message says how many there were.

        Recovery on synthetic cameras (``tests/test_effects_fit.py``): the std per intensity bin within 10 %, lag
        correlations within 0.05, channel correlations within 0.05, no banding on a camera without it (row σ below
        a tenth of the noise std), banding within 20 % where present.
        """
        return fit_noise(cls, source, target, estimator=estimator, taps=taps, banding=banding, rounds=rounds, seed=seed)

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
    ) -> Noise:
        """The noise stage of a profile, calibrated by simulated moments through the stages after it.

        :meth:`fit` (``estimator="excess"``, no rounds, no banding) against the deterministic ``sources`` gives the
        start; then the profile with the stage is simulated on every ``⌊N / calibration_pairs⌋``-th pair,
        the noise statistics of the flat pixels are measured on the simulations and on the captures, and the level
        table, kernels and banding are corrected (two rounds, then the levels once more, then banding against a
        simulated no-banding null). What the tone curve and the codec do to the noise is measured, not assumed.
        """
        start = cls.fit(list(sources), list(captures), estimator="excess", rounds=0, banding=False, seed=seed)
        step = max(1, len(cleans) // calibration_pairs) if calibration_pairs else 1
        chosen = list(range(0, len(cleans), step))
        measure = flat_noise_sums([cleans[i] for i in chosen])
        real, base = measure([captures[i] for i in chosen]), measure([sources[i] for i in chosen])
        return calibrate(start, lambda noise: simulate_with(noise, chosen), measure, real, base)

    def magnitude(self) -> float:
        """How strong this stage is: the noise std it adds to a mid-grey pixel (sRGB 0.5), mean over channels, in
        8-bit sRGB levels (banding aside)."""
        grey = torch.tensor(0.5)
        x = (srgb_to_linear(grey) if self.linear else grey).expand(1, 3, 1, 1)
        terms = self._terms(x, {})
        std = noise_std(x, terms["a"], terms["b"], terms.get("levels"))
        # A small std in linear light becomes std times the slope of the sRGB curve at that intensity.
        slope = (linear_to_srgb(x + 1e-4) - linear_to_srgb(x)) / 1e-4 if self.linear else torch.ones_like(x)
        return float((std * slope).mean()) * 255.0


def _count(value: Any, name: str) -> int:
    """A config count (knots, taps): a whole number, not a bool, a text or Infinity."""
    whole = isinstance(value, int) or (isinstance(value, float) and value.is_integer())
    if isinstance(value, bool) or not whole:
        raise ValueError(f"{name} must be a whole number, got {name}={value!r}")
    return int(value)


def _flag(value: Any, name: str) -> bool:
    """A config flag (columns, mixing): true or false, not the text "false" (which ``bool`` reads as true)."""
    if not isinstance(value, bool):
        raise TypeError(f"{name} must be True or False, got {name}={value!r} ({type(value).__name__})")
    return value


def _non_negative(tensor: Tensor, name: str) -> Tensor:
    if bool((tensor < 0).any()):
        raise ValueError(f"{name} must be non-negative, got {name}={tensor.tolist()}")
    return tensor


def _matrix(value: Tensor, name: str) -> Tensor:
    tensor = torch.as_tensor(value, dtype=torch.float32).detach().clone()
    if tensor.ndim != 2 or tensor.shape[0] != 3 or tensor.shape[1] < 1:
        raise ValueError(f"{name} must have shape (3, K) with K >= 1, got shape {tuple(tensor.shape)}")
    return tensor


def _taps(value: Tensor, name: str) -> Tensor:
    tensor = _matrix(value, name)
    if tensor.shape[1] % 2 == 0:
        raise ValueError(f"{name} must have an odd number of taps, got shape {tuple(tensor.shape)}")
    return tensor


def _unit_rows(tensor: Tensor, name: str) -> Tensor:
    norms = tensor.norm(dim=1, keepdim=True)
    if bool((norms == 0).any()) or not bool(torch.isfinite(norms).all()):
        raise ValueError(f"every row of {name} must be finite and non-zero, got {name}={tensor.tolist()}")
    return tensor / norms
