"""What machine a run ran on, recorded beside its timings.

Two 2-core hosts that report the same CPU model have run the same recipe stage 1.4-1.7x
apart (README, "The cost depends on the CPU, and on the day"), and a CPU without AVX512
trains the default in float32 at a fraction of the speed. A timing means little without
the machine, so the recipes write :func:`describe_machine` into ``results.json``: the CPU,
its vector extension, whether it has native bfloat16 matmuls, the torch threads, and the
float32 matmul rate measured at the start of the run (:func:`matmul_gflops`), a number
that compares two hosts' arithmetic where their model names do not. It does not see
what a run loses to Python overhead or to other processes later on.

Examples:
    >>> machine = describe_machine(measure=False)
    >>> sorted(machine)[:3]
    ['cpu', 'cpu_capability', 'cpu_native_bfloat16']
    >>> machine["logical_cpus"] >= 1
    True
"""

from __future__ import annotations

import os
import platform
import time
from pathlib import Path

import torch

from simdist.utils.precision import native_bfloat16


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux, else :func:`platform.processor`)."""
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        for line in cpuinfo.read_text(errors="replace").splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or "unknown"


def matmul_gflops(rows: int = 2048, width: int = 512, seconds: float = 0.3) -> float:
    """Float32 GFLOP/s of ``[rows, width] @ [width, width]`` on the CPU with torch's
    current threads, repeated for about ``seconds`` (the shape of the SimDist default's
    largest matmuls: see ``benchmarks/pretrain_update_compute.py``)."""
    if rows < 1 or width < 1 or seconds <= 0:
        raise ValueError(f"rows, width and seconds must be positive (got {rows}, {width}, "
                         f"{seconds})")
    a, w = torch.randn(rows, width), torch.randn(width, width)
    for _ in range(3):  # warm-up: allocator and kernel selection
        a @ w
    repeats, start = 0, time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds or repeats < 3:
        a @ w
        repeats += 1
    return 2 * rows * width * width * repeats / elapsed / 1e9


def describe_machine(measure: bool = True) -> dict:
    """The machine as a JSON-ready dict: ``cpu`` (model name), ``logical_cpus``,
    ``cpu_capability`` (PyTorch's: e.g. ``"AVX2"``, ``"AVX512"``), ``cpu_native_bfloat16``,
    ``torch``, ``torch_threads``, ``cuda`` (the device's name, or ``None``) and, with
    ``measure``, ``matmul_gflops`` (float32, this many threads; ~0.3 s)."""
    machine = {
        "cpu": cpu_model(),
        "logical_cpus": os.cpu_count() or 1,
        "cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "cpu_native_bfloat16": native_bfloat16("cpu"),
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
    }
    if measure:
        machine["matmul_gflops"] = round(matmul_gflops(), 1)
    return machine


def machine_line(machine: dict) -> str:
    """One line for a run's log, e.g. ``"AMD EPYC, 2 CPUs (AVX2, no native bfloat16),
    2 torch threads, float32 matmul 158 GFLOP/s"``."""
    bf16 = "native bfloat16" if machine["cpu_native_bfloat16"] else "no native bfloat16"
    line = (f"{machine['cpu']}, {machine['logical_cpus']} CPUs ({machine['cpu_capability']}, "
            f"{bf16}), {machine['torch_threads']} torch threads")
    if "matmul_gflops" in machine:
        line += f", float32 matmul {machine['matmul_gflops']:.0f} GFLOP/s"
    if machine["cuda"]:
        line += f", CUDA: {machine['cuda']}"
    return line
