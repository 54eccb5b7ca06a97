"""Which reduced precisions keep the network within one 8-bit level of float32, and what int8 would buy.

Plain script, not a test. ``precision="auto"`` may only pick arithmetic whose 8-bit output stays within one level of
float32 on at least 99.9 % of pixels of natural images (issue 8). For each built-in profile's network, on four
scikit-image photos, this compares with float32:

- ``bfloat16``: the module under autocast (what ``precision="bfloat16"`` computes, up to summation order);
- ``int8_weights``: every layer's weights rounded to 8 bits per output channel, activations in float32;
- ``int8_activations``: the three hidden activations rounded to 8 bits (unsigned, one scale per tensor set by the
  largest value on these photos), weights in float32;
- ``int8``: both, which is what an int8 inference path computes.

It also times the network's largest layer (3×3 conv, 64 → 128 channels at 112² → 56²) in float32, in bfloat16 (plain
``conv2d``; emulated where the CPU lacks it) and in oneDNN's int8 kernel, to show what each would buy; and it counts
the encoder channels that ReLU leaves at zero over a whole photo, which the CPU plan's first decoder product skips.
Run from the repo root::

    .venv/bin/python bench/bench_precision.py         # writes out/bench/precision.json
"""

from __future__ import annotations

import argparse
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from bench_transform import Case, interleaved_rates
from machine import write_json
from torch import Tensor

from camdegrade import list_profiles, load_profile
from camdegrade.network import DomainShiftNet

PHOTOS = ("astronaut", "chelsea", "coffee", "rocket")
REQUIRED = 0.999


def photos() -> list[Tensor]:
    from skimage import data

    return [torch.from_numpy(getattr(data, name)()).permute(2, 0, 1)[None].float() / 255.0 for name in PHOTOS]


def round_weights(weight: Tensor, out_dim: int) -> Tensor:
    """Symmetric 8-bit rounding with one scale per output channel (``out_dim`` of the weight)."""
    dims = [d for d in range(weight.ndim) if d != out_dim]
    scale = weight.abs().amax(dim=dims, keepdim=True).clamp_min(1e-12) / 127.0
    return (weight / scale).round().clamp(-127, 127) * scale


def round_activation(hidden: Tensor, largest: float) -> Tensor:
    """Unsigned 8-bit rounding of ReLU outputs on ``[0, largest]``."""
    scale = largest / 255.0
    return (hidden / scale).round().clamp(0, 255) * scale


def hidden_maxima(network: DomainShiftNet, images: list[Tensor]) -> list[float]:
    """The largest value of each hidden activation over ``images`` (the int8 calibration)."""
    maxima = [0.0, 0.0, 0.0]
    for image in images:
        _, hidden = forward(network, image, lambda h, _: h, lambda w, _: w)
        maxima = [max(m, float(h.max())) for m, h in zip(maxima, hidden)]
    return maxima


def forward(
    network: DomainShiftNet,
    image: Tensor,
    activation: Callable[[Tensor, int], Tensor],
    weights: Callable[[Tensor, int], Tensor],
) -> tuple[Tensor, list[Tensor]]:
    """The module's arithmetic with ``weights(w, out_dim)`` and ``activation(h, layer)`` applied in between."""
    pad = (0, -image.shape[-1] % 4, 0, -image.shape[-2] % 4)
    x = F.pad(image, pad, mode="replicate")
    e1, e2, d1, d2 = network.encode1, network.encode2, network.decode1, network.decode2
    h1 = activation(F.relu(F.conv2d(x, weights(e1.weight, 0), e1.bias, stride=2, padding=1)), 0)
    h2 = activation(F.relu(F.conv2d(h1, weights(e2.weight, 0), e2.bias, stride=2, padding=1)), 1)
    h3 = activation(F.relu(F.conv_transpose2d(h2, weights(d1.weight, 1), d1.bias, stride=2)), 2)
    out = torch.sigmoid(F.conv_transpose2d(h3, weights(d2.weight, 1), d2.bias, stride=2))
    return out[..., : image.shape[-2], : image.shape[-1]], [h1, h2, h3]


def levels(image: Tensor) -> Tensor:
    return image.mul(255.0).round()


def agreement(network: DomainShiftNet, images: list[Tensor]) -> dict[str, dict[str, float]]:
    maxima = hidden_maxima(network, images)
    keep = lambda value, _: value  # noqa: E731
    variants: dict[str, Callable[[Tensor], Tensor]] = {
        "bfloat16": lambda x: _autocast(network, x),
        "int8_weights": lambda x: forward(network, x, keep, round_weights)[0],
        "int8_activations": lambda x: forward(network, x, lambda h, i: round_activation(h, maxima[i]), keep)[0],
        "int8": lambda x: forward(network, x, lambda h, i: round_activation(h, maxima[i]), round_weights)[0],
    }
    results = {}
    for name, run in variants.items():
        within = same = total = 0
        largest = 0.0
        for image in images:
            difference = (levels(network(image)) - levels(run(image))).abs()
            within += int((difference <= 1).sum())
            same += int((difference == 0).sum())
            total += difference.numel()
            largest = max(largest, float(difference.max()))
        results[name] = {
            "within_one_level": round(within / total, 5),
            "identical": round(same / total, 4),
            "largest_difference": largest,
            "meets_999": within / total >= REQUIRED,
        }
    return results


def _autocast(network: DomainShiftNet, image: Tensor) -> Tensor:
    with torch.autocast("cpu", dtype=torch.bfloat16):
        return network(image).float()


def zero_channels(network: DomainShiftNet, images: list[Tensor]) -> list[int]:
    """How many of the encoder's output channels are zero over each whole image."""
    keep = lambda value, _: value  # noqa: E731
    return [int((forward(network, image, keep, keep)[1][1].amax(dim=(0, 2, 3)) == 0).sum()) for image in images]


def conv2_milliseconds(repeats: int) -> dict[str, float | None]:
    """Median ms of the 64 → 128 channel 3×3/2 convolution on 112² in float32, bfloat16 and int8 (oneDNN), timed in
    interleaved rounds (see ``bench_transform.interleaved_rates``)."""
    generator = torch.Generator().manual_seed(0)
    hidden = torch.rand(1, 64, 112, 112, generator=generator).contiguous(memory_format=torch.channels_last)
    weight = torch.randn(128, 64, 3, 3, generator=generator).contiguous(memory_format=torch.channels_last)
    hidden_bf16, weight_bf16 = hidden.bfloat16(), weight.bfloat16()
    cases = {
        "float32": Case(lambda: F.conv2d(hidden, weight, stride=2, padding=1), calls=20),
        "bfloat16": Case(lambda: F.conv2d(hidden_bf16, weight_bf16, stride=2, padding=1), calls=3),
    }
    try:
        import torch.ao.nn.quantized as quantized

        torch.backends.quantized.engine = "onednn"
        conv = quantized.Conv2d(64, 128, 3, stride=2, padding=1)
        quantized_hidden = torch.quantize_per_tensor(hidden, 0.01, 0, torch.quint8)
        cases["int8"] = Case(lambda: conv(quantized_hidden), calls=20)
    except (ImportError, RuntimeError, AttributeError) as error:
        print(f"int8 convolution unavailable here: {error}")
    rates = interleaved_rates(cases, repeats)
    return {name: round(1000.0 / rates[name], 3) if name in rates else None for name in ("float32", "bfloat16", "int8")}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("out/bench/precision.json"))
    args = parser.parse_args(argv)
    warnings.filterwarnings("ignore")  # torch.ao's deprecation notice is not what is measured
    torch.set_num_threads(args.threads)
    images = photos()
    record: dict[str, Any] = {"required_within_one_level": REQUIRED, "photos": list(PHOTOS), "profiles": {}}
    with torch.no_grad():
        for name in list_profiles():
            network = load_profile(name).network
            if network is None:
                continue
            zeros, channels = zero_channels(network, images), network.encode2.out_channels
            record["profiles"][name] = {**agreement(network, images), "zero_encoder_channels": zeros}
            record["profiles"][name]["encoder_channels"] = channels
            print(f"{name:20s} encoder channels zero over each whole photo: {zeros} of {channels}")
            for variant, numbers in record["profiles"][name].items():
                if variant.startswith(("zero", "encoder")):
                    continue
                print(
                    f"{name:20s} {variant:17s} within one level {numbers['within_one_level']:.5f} "
                    f"(identical {numbers['identical']:.4f}, largest {numbers['largest_difference']:.0f}) "
                    f"{'meets' if numbers['meets_999'] else 'misses'} the 99.9 % bar",
                    flush=True,
                )
        record["conv2_ms"] = conv2_milliseconds(repeats=9)
    print(f"largest layer, ms per 224² image: {record['conv2_ms']}")
    write_json(args.out, record)
    return record


if __name__ == "__main__":
    main()
