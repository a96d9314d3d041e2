"""SimDist pretraining updates/s per model size, float32 vs bfloat16 autocast, same run.

One update = ``SimDistAgent.pretrain_update`` on a batch shaped like the recipe's (32
slices of 16 steps, 89-D observations, 12-D actions, horizon 5): encode, roll the dynamics,
the four loss terms, backward, clip, Adam. ``bfloat16`` is ``SimDistConfig(mixed_precision=
"bfloat16")``; the ratio is against float32 on the same size in the same process.

Usage:
    python benchmarks/simdist_pretrain_precision.py                 # small and wide
    python benchmarks/simdist_pretrain_precision.py --sizes wide --updates 50 --threads 1
    python benchmarks/simdist_pretrain_precision.py --device cuda --sizes small wide paper --slices 32 256

On CUDA every timed loop ends with ``torch.cuda.synchronize()`` (wall-clock, not launch time).
"""

from __future__ import annotations

import argparse
import time

import torch
from tensordict import TensorDict

import simdist  # noqa: F401
from simdist.agents import SimDistAgent, SimDistConfig
from simdist.modules import SimDistWorldModel


def make_batch(slices: int, length: int, obs_dim: int, action_dim: int) -> TensorDict:
    return TensorDict({
        "observation": torch.randn(slices, length, obs_dim),
        "action": torch.rand(slices, length, action_dim) * 2 - 1,
        "is_init": torch.zeros(slices, length, 1, dtype=torch.bool),
        "expert_active": torch.ones(slices, length, 1, dtype=torch.bool),
        "next": {"reward": torch.rand(slices, length, 1)},
        "value_target": torch.rand(slices, length, 1) * 50,
    }, [slices, length])


def synchronize(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def updates_per_second(size: str, precision: str, batch: TensorDict, updates: int,
                       device: torch.device) -> float:
    torch.manual_seed(0)
    wm = SimDistWorldModel.build(batch["observation"].shape[-1], batch["action"].shape[-1], size=size)
    agent = SimDistAgent(wm, SimDistConfig(size=size, mixed_precision=precision)).to(device)
    batch = batch.to(device)
    for _ in range(3):  # warm-up (allocator, oneDNN / cuBLAS kernels)
        agent.pretrain_update(batch)
    synchronize(device)
    start = time.perf_counter()
    for _ in range(updates):
        agent.pretrain_update(batch)
    synchronize(device)
    return updates / (time.perf_counter() - start)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=["small", "wide"])
    parser.add_argument("--updates", type=int, default=30)
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    parser.add_argument("--device", default="cpu", help="cpu or cuda")
    parser.add_argument("--slices", type=int, nargs="+", default=[32],
                        help="slices of 16 steps per update (the recipe's default: 32)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu"
    print(f"torch {torch.__version__}, {name}, threads {torch.get_num_threads()}")
    print(f"{'size':6s} {'slices':>6s} {'float32 upd/s':>14s} {'bfloat16 upd/s':>15s} {'speed-up':>9s}")
    for slices in args.slices:
        batch = make_batch(slices, 16, 89, 12)
        for size in args.sizes:
            fp32 = updates_per_second(size, "none", batch, args.updates, device)
            bf16 = updates_per_second(size, "bfloat16", batch, args.updates, device)
            print(f"{size:6s} {slices:6d} {fp32:14.1f} {bf16:15.1f} {bf16 / fp32:8.2f}x")


if __name__ == "__main__":
    main()
