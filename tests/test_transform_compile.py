"""``CameraDegrade`` under PyTorch's graph tools (issue 44): ``torch.jit.trace`` is refused at once with a message that
says why and what to do; ``torch.compile`` runs the transform eagerly, so a seeded call gives the same bytes as
without it (it failed in Inductor after a minute)."""

from __future__ import annotations

import time

import pytest
import torch

from camdegrade import CameraDegrade

torch.set_num_threads(1)


def _image() -> torch.Tensor:
    return torch.randint(0, 256, (2, 3, 40, 48), generator=torch.Generator().manual_seed(3), dtype=torch.uint8)


@pytest.mark.filterwarnings("ignore:`torch.jit.trace(_method)?` is deprecated:FutureWarning")
def test_jit_trace_is_refused_at_once_with_what_to_do() -> None:
    degrade = CameraDegrade("lowcost-robot-sim", seed=0)
    started = time.perf_counter()
    with pytest.raises(RuntimeError, match=r"CameraDegrade\(\) cannot be traced with torch\.jit\.trace: .*eagerly"):
        torch.jit.trace(degrade, _image().float() / 255)
    assert time.perf_counter() - started < 30  # refused before any degradation, not deep inside the network


@pytest.mark.filterwarnings("ignore:`torch.jit.script` is deprecated:FutureWarning")
def test_jit_script_is_still_refused_by_torchvision() -> None:
    with pytest.raises(RuntimeError, match=r"CameraDegrade cannot be JIT scripted"):
        torch.jit.script(CameraDegrade("lowcost-robot-sim", seed=0))


@pytest.mark.slow  # importing and setting up torch._dynamo takes seconds
def test_torch_compile_gives_the_same_bytes_as_eager_for_a_seed() -> None:
    eager = CameraDegrade("lowcost-robot-sim", seed=0)
    compiled = torch.compile(CameraDegrade("lowcost-robot-sim", seed=0))
    for _ in range(2):  # the second call: the generator advanced alike
        assert torch.equal(compiled(_image()), eager(_image()))

    @torch.compile
    def model_after(image: torch.Tensor) -> torch.Tensor:  # a compiled pipeline with the transform inside
        return eager(image).float().mean((-2, -1))

    reference = CameraDegrade("lowcost-robot-sim", seed=5)
    eager.__init__("lowcost-robot-sim", seed=5)
    assert torch.equal(model_after(_image()), reference(_image()).float().mean((-2, -1)))
