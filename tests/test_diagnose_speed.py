"""What makes the diagnosis faster gives the same bytes as the slower way (issue 42: ``diagnose`` on 100 pairs of 256²
within 120 s, bench/bench_diagnose_time.py): the box mean, the strength-check gaps kept per profile, the fine-tune's
frozen encoder features, the critic's folds side by side, and the CLI's sleeping OpenMP threads; and the bench's
split of the wall time by thread (bench/diagnose_schedstat.py)."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest
import torch
import torch.nn.functional as F

import camdegrade.fitting.network.finetune as finetune
from camdegrade._runtime.threads import side_by_side, torch_threads
from camdegrade.diagnose.attribution.evaluation import GapsByContent
from camdegrade.diagnose.heldout import HeldOut
from camdegrade.effects import Blur, Noise
from camdegrade.functional.analysis.images import box_mean
from camdegrade.measures.critic.explain import crossfit_critic_test
from camdegrade.network import LocalAffineNet
from camdegrade.profile import CameraProfile
from conftest import load_script


def _pooled_box_mean(image: torch.Tensor, size: int) -> torch.Tensor:
    """The box mean as avg_pool2d computes it (what box_mean was until 2026-11-29)."""
    flat, half = image.reshape(-1, 1, *image.shape[-2:]), size // 2
    out = F.avg_pool2d(flat, (1, size), stride=1, padding=(0, half), count_include_pad=False)
    return F.avg_pool2d(out, (size, 1), stride=1, padding=(half, 0), count_include_pad=False).reshape(image.shape)


@pytest.mark.parametrize("shape", [(3, 64, 48), (2, 3, 7, 5), (3, 4, 9), (40, 40)])
@pytest.mark.parametrize("size", [1, 3, 5, 9])
def test_box_mean_gives_the_bytes_of_avg_pool2d(shape: tuple[int, ...], size: int) -> None:
    image = torch.rand(shape, generator=torch.Generator().manual_seed(size), dtype=torch.float32) * 255.0 - 30.0
    assert torch.equal(box_mean(image, size), _pooled_box_mean(image, size))


def _pairs(count: int, seed: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
    generator = torch.Generator().manual_seed(seed)
    cleans = [torch.rand(3, 32, 32, generator=generator) for _ in range(count)]
    return [(clean, (clean + 0.02 * torch.randn(clean.shape, generator=generator)).clamp(0, 1)) for clean in cleans]


def test_check_gaps_measure_a_profile_once_and_give_its_gap(monkeypatch: pytest.MonkeyPatch) -> None:
    check = HeldOut.build(_pairs(4, 0), 0, "strength-check")
    profile = CameraProfile(None, [Blur(sigma_x=0.8), Noise(a=0.001)])
    check.calibrate(profile)
    expected = check.gap(check.statistics(profile)[0])
    measured = []
    statistics = HeldOut.statistics
    monkeypatch.setattr(HeldOut, "statistics", lambda self, p, **kw: measured.append(p) or statistics(self, p, **kw))
    gaps = GapsByContent(check)
    same = CameraProfile(None, [Blur(sigma_x=0.8), Noise(a=0.001)])  # another object, the same content
    assert gaps(profile) == expected and gaps(same) == expected
    assert gaps(CameraProfile(None, [Blur(sigma_x=1.6), Noise(a=0.001)])) != expected
    assert len(measured) == 2 and len(gaps) == 2


class _Recomputed:
    """The encoder computed at every step, as the fine-tune did until 2026-11-29."""

    def __init__(self, encode):
        self.encode = encode

    def __call__(self, image):
        return self.encode(image)


@pytest.mark.slow  # 5 s on the shared 2-core machine
def test_the_finetune_gives_the_same_weights_with_its_features_computed_once(monkeypatch) -> None:
    torch.manual_seed(0)
    network = LocalAffineNet(width=8, curves=True)
    with torch.no_grad():
        for parameter in network.parameters():
            parameter.add_(0.01 * torch.randn(parameter.shape))
    profile = CameraProfile(network.requires_grad_(False), [Blur(sigma_x=0.7)])
    pairs = _pairs(2, 1)
    cleans, captures = [c for c, _ in pairs], [r for _, r in pairs]
    fast = finetune.finetune_network(profile, cleans, captures, steps=3)
    monkeypatch.setattr(finetune, "_FrozenFeatures", _Recomputed)
    slow = finetune.finetune_network(profile, cleans, captures, steps=3)
    assert fast.state_dict().keys() == slow.state_dict().keys()
    assert all(torch.equal(fast.state_dict()[key], slow.state_dict()[key]) for key in fast.state_dict())
    assert "encode" not in vars(fast)  # the class's method again
    assert not torch.equal(fast.decode2.weight, network.decode2.weight)  # it did train


def test_side_by_side_keeps_the_order_and_gives_each_call_one_thread() -> None:
    with torch_threads(2):
        assert side_by_side([lambda: torch.get_num_threads(), lambda: "b", lambda: 3]) == [1, "b", 3]
        assert torch.get_num_threads() == 2  # the caller's own count is untouched
    with torch_threads(1):
        assert side_by_side([torch.get_num_threads, lambda: "b"]) == [1, "b"]


@pytest.mark.slow  # 4 s on the shared 2-core machine
def test_a_cross_fit_critic_gives_the_same_bytes_with_one_thread_and_two() -> None:
    pairs = _pairs(6, 2)
    cleans, reals = [c for c, _ in pairs], [r for _, r in pairs]
    sims = [(c + 0.018 * torch.randn(c.shape, generator=torch.Generator().manual_seed(9))).clamp(0, 1) for c in cleans]
    trains = [index % 2 == 0 for index in range(6)]
    results = []
    for threads in (1, 2):
        with torch_threads(threads):
            result, explanation, folds = crossfit_critic_test((cleans, reals, sims), trains, 0, steps=15)
        results.append((result.accuracy, result.low, result.high, folds, [p.margin for p in explanation.surest]))
    assert results[0] == results[1]


@pytest.mark.parametrize(("given", "expected"), [(None, "PASSIVE"), ("active", "active")])
def test_the_command_line_lets_openmp_threads_sleep_unless_told(given: str | None, expected: str) -> None:
    environment = {key: value for key, value in os.environ.items() if key != "OMP_WAIT_POLICY"}
    if given is not None:
        environment["OMP_WAIT_POLICY"] = given
    code = "import os; from camdegrade.cli import main; main(['list']); print(os.environ['OMP_WAIT_POLICY'])"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=environment, check=True)
    assert done.stdout.strip().splitlines()[-1] == expected


def test_the_idle_machine_estimate_schedules_tasks_as_the_pool_does() -> None:
    """bench/diagnose_schedstat.py: each task goes, in order, to the first worker free (ThreadPoolExecutor.map)."""
    schedstat = load_script("bench/diagnose_schedstat.py", "diagnose_schedstat")
    assert schedstat.makespan([5.0, 1.0, 1.0, 1.0, 1.0, 1.0], 2) == 5.0
    assert schedstat.makespan([1.0, 1.0, 5.0], 2) == 6.0
    assert schedstat.makespan([2.0, 2.0], 1) == 4.0


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/thread-self/schedstat")
def test_the_schedstat_recorder_splits_a_task_into_cpu_and_blocked() -> None:
    schedstat = load_script("bench/diagnose_schedstat.py", "diagnose_schedstat")
    recorder = schedstat.Recorder(side_by_side)
    with torch_threads(2):
        assert recorder([lambda: time.sleep(0.2) or "slept", lambda: sum(range(10**6))]) == ["slept", sum(range(10**6))]
    (call,) = recorder.calls
    (slept_wall, slept_cpu, slept_waiting), (summed_wall, summed_cpu, summed_waiting) = call["tasks"]
    assert call["workers"] == 2 and slept_wall >= 0.2 and slept_wall - slept_cpu - slept_waiting >= 0.19
    assert summed_cpu > 0 and summed_cpu + summed_waiting <= summed_wall + 1e-3


def test_the_schedstat_recorder_replaces_side_by_side_where_it_was_imported(monkeypatch: pytest.MonkeyPatch) -> None:
    import camdegrade._runtime.threads as threads
    import camdegrade.diagnose.attribution.evaluation as evaluation

    schedstat = load_script("bench/diagnose_schedstat.py", "diagnose_schedstat")
    original = threads.side_by_side
    for module in (threads, evaluation, sys.modules[__name__]):  # this module imported it too
        monkeypatch.setattr(module, "side_by_side", original)  # restored after the test
    recorder = schedstat.install()
    assert threads.side_by_side is recorder and evaluation.side_by_side is recorder
    assert recorder.side_by_side is original
