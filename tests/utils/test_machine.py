"""The machine description the recipes write beside their timings."""

import json

import pytest
import torch

import simdist.utils.machine as machine_module
from simdist.utils.machine import cpu_model, describe_machine, machine_line, matmul_gflops
from simdist.utils.precision import native_bfloat16


def test_description_is_json_ready_and_matches_torch():
    machine = describe_machine()
    assert json.loads(json.dumps(machine)) == machine
    assert machine["cpu"] == cpu_model() and machine["cpu"]
    assert machine["cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert machine["cpu_native_bfloat16"] == native_bfloat16("cpu")
    assert machine["torch_threads"] == torch.get_num_threads()
    assert machine["matmul_gflops"] > 0
    assert "matmul_gflops" not in describe_machine(measure=False)


def test_matmul_rate_counts_two_flops_per_multiply_add(monkeypatch):
    # a clock that ticks 0.125 s per read: calls at 0.125, 0.25 (< 0.3 s) and a third at
    # 0.375 (at least three calls), then it stops at 0.5 s
    ticks = iter(range(100))
    monkeypatch.setattr(machine_module.time, "perf_counter", lambda: next(ticks) * 0.125)
    rate = matmul_gflops(64, 32, seconds=0.3)
    assert rate == pytest.approx(2 * 64 * 32 * 32 * 3 / 0.5 / 1e9)


@pytest.mark.parametrize("args", [(0, 512, 0.1), (16, 0, 0.1), (16, 16, 0.0)])
def test_matmul_rate_refuses_empty_work(args):
    with pytest.raises(ValueError, match="must be positive"):
        matmul_gflops(*args)


def test_line_names_capability_threads_and_rate():
    machine = {"cpu": "Some CPU", "logical_cpus": 2, "cpu_capability": "AVX2",
               "cpu_native_bfloat16": False, "torch": "2", "torch_threads": 2, "cuda": None,
               "matmul_gflops": 157.6}
    assert machine_line(machine) == ("Some CPU, 2 CPUs (AVX2, no native bfloat16), 2 torch "
                                     "threads, float32 matmul 158 GFLOP/s")
    assert machine_line({**machine, "cuda": "H100"}).endswith("CUDA: H100")
