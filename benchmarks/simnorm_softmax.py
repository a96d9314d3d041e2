"""SimNorm's softmax per group of 8: torch's last-dimension kernel vs a non-last dimension.

``simnorm`` (src/simdist/modules/encoders.py) normalises each group of 8 latent entries
with a softmax. On AVX512 CPUs torch's kernel for a softmax over a last dimension shorter
than a vector register (16 float32 lanes) is several times slower per element than the
same softmax taken along a non-last dimension, so ``simnorm`` takes the latter there
(``_SHORT_GROUP_LANES``). This measures, in one run and one process:

1. the operation alone (forward, and forward + backward) at the planner's and the
   pretraining's shapes, the direct call against the one ``simnorm`` makes;
2. the recipe's default model and planner (``Config`` / ``new_agent`` of
   recipes/simdist_quadruped.py: H20 x 64 x 3, 90% prior proposals) planning for 32
   worlds, per latent size, with ``simnorm``'s short-group path off and on;
3. one pretraining update of that model (32 slices of 16 steps), off and on.

Usage:
    python benchmarks/simnorm_softmax.py --threads 1
    python benchmarks/simnorm_softmax.py --threads 1 --latents 128 256 --precision bfloat16
"""

from __future__ import annotations

import argparse

import torch
from tensordict import TensorDict

from planner_latency import latency_ms  # benchmarks/ (the script's folder is on sys.path)
from simdist_pretrain_precision import make_batch

from simdist.modules import encoders
from simdist.pipelines.simdist import Config, new_agent


def direct(z: torch.Tensor) -> torch.Tensor:
    return torch.softmax(z.reshape(z.shape[0], -1, 8), -1).reshape(z.shape)


def along_non_last(z: torch.Tensor) -> torch.Tensor:
    return torch.softmax(z.reshape(z.shape[0], -1, 8).transpose(1, 2), 1).transpose(1, 2) \
        .reshape(z.shape)


def op_row(rows: int, latent: int, calls: int) -> str:
    z = torch.randn(rows, latent)
    weights = torch.randn(rows, latent)
    out = []
    for fn in (direct, along_non_last):
        forward = latency_ms(lambda: fn(z), calls)
        x = z.clone().requires_grad_()
        both = latency_ms(lambda: (fn(x) * weights).sum().backward(), calls)
        out.append((forward, both))
    (f0, b0), (f1, b1) = out
    return (f"{rows:6d} x {latent:4d} {f0:9.2f} {f1:9.2f} {f0 / f1:6.1f}x "
            f"{b0:10.2f} {b1:10.2f} {b0 / b1:6.1f}x")


def with_lanes(lanes: int, fn):
    saved = encoders._SHORT_GROUP_LANES
    encoders._SHORT_GROUP_LANES = lanes
    try:
        return fn()
    finally:
        encoders._SHORT_GROUP_LANES = saved


def recipe_agent(latent: int, precision: str):
    """The recipe's default agent (model and planner) with this latent and precision."""
    torch.manual_seed(0)
    cfg = Config(model_latent_dim=latent, mixed_precision=precision,
                 planner_precision=precision)
    return new_agent(cfg, obs_dim=89, action_dim=12), cfg.planner()


def planner_ms(latent: int, precision: str, calls: int) -> float:
    agent, planner_config = recipe_agent(latent, precision)
    planner = agent.policy(-torch.ones(12), torch.ones(12), planner_config, seed=0)
    td = TensorDict({"latent": torch.rand(32, latent)}, [32])
    return latency_ms(lambda: planner.planner(td.clone()), calls)


def update_ms(latent: int, precision: str, calls: int) -> float:
    agent, _ = recipe_agent(latent, precision)
    batch = make_batch(32, 16, 89, 12)
    return latency_ms(lambda: agent.pretrain_update(batch), calls)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    parser.add_argument("--latents", type=int, nargs="+", default=[128, 256])
    parser.add_argument("--precision", default="bfloat16",
                        help="planner and training precision (none: float32)")
    parser.add_argument("--calls", type=int, default=15)
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, CPU capability {torch.backends.cpu.get_cpu_capability()}, "
          f"threads {torch.get_num_threads()}, simnorm short-group lanes "
          f"{encoders._SHORT_GROUP_LANES}")
    print(f"\nsoftmax per group of 8 (ms)   {'direct':>9s} {'non-last':>9s} {'ratio':>7s} "
          f"{'direct+bwd':>10s} {'non-last+bwd':>10s} {'ratio':>7s}")
    for latent in args.latents:
        for rows in (512, 2048):  # a pretraining batch's latents; the planner's 32 x 64
            print("  " + op_row(rows, latent, args.calls))
    print(f"\n{'latent':>6s} {'planner ms direct':>18s} {'simnorm':>8s} {'ratio':>6s} "
          f"{'update ms direct':>17s} {'simnorm':>8s} {'ratio':>6s}")
    for latent in args.latents:
        plan = [with_lanes(lanes, lambda: planner_ms(latent, args.precision, args.calls))
                for lanes in (0, 16)]
        upd = [with_lanes(lanes, lambda: update_ms(latent, args.precision, args.calls))
               for lanes in (0, 16)]
        print(f"{latent:6d} {plan[0]:18.0f} {plan[1]:8.0f} {plan[0] / plan[1]:5.2f}x "
              f"{upd[0]:17.0f} {upd[1]:8.0f} {upd[0] / upd[1]:5.2f}x")


if __name__ == "__main__":
    main()
