"""Is the recipe's pretraining update compute-bound? Its FLOPs, its GFLOP/s against a plain
matmul's in the same process, and what ``torch.compile`` of the loss buys.

The model and batch are the recipe's default (``recipes/simdist_quadruped.py``'s
``Config()``: the "wide" world model, a 256-dimensional latent, horizon 5, 32 slices of 16
steps, the precision ``"auto"`` resolves to on this machine). The FLOPs are counted by
``torch.profiler`` (matmuls only, forward and backward) over a few updates; the reference
is ``[rows, 512] @ [512, 512]`` at the update's largest matmul, timed with the same
threads. A ratio near 1 says the update runs at the machine's matmul speed: graph
compilers cannot make it much faster, only less work or faster arithmetic can (bfloat16
where the CPU has it, see ``simdist_pretrain_precision.py``).

Usage:
    python benchmarks/pretrain_update_compute.py                 # eager only
    python benchmarks/pretrain_update_compute.py --compile       # and torch.compile (first call 7-60 s)
"""

from __future__ import annotations

import argparse
import time

import torch
from torch.profiler import ProfilerActivity, profile

from simdist.pipelines.simdist import Config, new_agent
from simdist.utils.machine import matmul_gflops
from simdist.utils.precision import resolve_precision
from simdist_pretrain_precision import make_batch


def ms_per_update(update, batch, updates: int) -> float:
    for _ in range(3):  # warm-up (allocator, kernels; compilation when compiled)
        update(batch)
    start = time.perf_counter()
    for _ in range(updates):
        update(batch)
    return 1000 * (time.perf_counter() - start) / updates


def flops_per_update(update, batch, updates: int = 3) -> float:
    with profile(activities=[ProfilerActivity.CPU], with_flops=True) as prof:
        for _ in range(updates):
            update(batch)
    return sum(event.flops for event in prof.key_averages()) / updates


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--updates", type=int, default=40)
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    parser.add_argument("--compile", action="store_true", help="also torch.compile the loss")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    cfg = Config()
    batch = make_batch(cfg.batch_slices, cfg.slice_len, 89, 12)
    # the update's largest matmuls: value and reward heads on every start's H + 1 latents
    rows = cfg.batch_slices * (cfg.slice_len - cfg.model_horizon) * (cfg.model_horizon + 1)
    torch.manual_seed(0)
    agent = new_agent(cfg, 89, 12)
    precision = resolve_precision(cfg.mixed_precision, "cpu")
    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}, "
          f"precision {precision}, {sum(p.numel() for p in agent.world_model.parameters())} "
          f"parameters")
    reference = matmul_gflops(rows, seconds=1.0)
    flops = flops_per_update(agent.pretrain_update, batch)
    eager = ms_per_update(agent.pretrain_update, batch, args.updates)
    achieved = flops / eager / 1e6
    print(f"matmul [{rows}, 512] @ [512, 512]: {reference:.1f} GFLOP/s (reference)")
    print(f"update: {flops / 1e9:.2f} GFLOP (matmuls), eager {eager:.1f} ms = {achieved:.1f} "
          f"GFLOP/s = {achieved / reference:.2f}x the reference")
    print(f"the recipe's {cfg.pretrain_updates} updates: {cfg.pretrain_updates * eager / 6e4:.1f} "
          f"min at this speed")
    if args.compile:
        agent.pretrain_loss = torch.compile(agent.pretrain_loss)
        start = time.perf_counter()
        agent.pretrain_update(batch)
        first = time.perf_counter() - start
        compiled = ms_per_update(agent.pretrain_update, batch, args.updates)
        print(f"torch.compile(loss): {compiled:.1f} ms = {eager / compiled:.2f}x eager "
              f"(first call {first:.0f} s)")


if __name__ == "__main__":
    main()
