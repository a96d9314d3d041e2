"""Planner latency per action: simdist's LatentMPPIPlanner vs TorchRL's MPPIPlanner.

Both plan over the same networks (a SimDist world model: MLP dynamics, reward and value
heads, latent 64, 12-D actions like the quadruped) at the same horizon / samples /
iterations / elites, one environment, in the same run. TorchRL's planner needs a
``ModelBasedEnvBase`` (it rolls out the world model through TensorDict env steps) and an
advantage module (``TDLambdaEstimator`` over the value head), built here from the same
modules. Latency = median wall time of ``planner(td)`` over many calls.

Usage:
    python benchmarks/planner_latency.py             # CPU default + SimDist reference
    python benchmarks/planner_latency.py --quick
    python benchmarks/planner_latency.py --compile   # also the torch.compile path
    python benchmarks/planner_latency.py --size wide --batch 32 --configs "recipe H20" --precision bfloat16
    # the recipe's model and the cost of its lambda-return score (ratio column: to the
    # first config listed)
    python benchmarks/planner_latency.py --size wide --latent-dim 256 --simnorm-groups 32 \
        --batch 32 --precision bfloat16 --configs "recipe H20" "recipe H20 lambda" \
        "recipe H20 lambda k2" "recipe H20 lambda k4"
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torchrl.data import Bounded, Composite, Unbounded
from torchrl.envs.model_based import ModelBasedEnvBase
from torchrl.modules import MPPIPlanner, ValueOperator, WorldModelWrapper
from torchrl.objectives.value import TDLambdaEstimator

import simdist  # noqa: F401
from simdist.modules import SimDistWorldModel
from simdist.modules.planner import LatentMPPIPlanner, PlannerConfig


class LatentEnv(ModelBasedEnvBase):
    """The world model's latent dynamics as a TorchRL model-based env (for MPPIPlanner)."""

    def __init__(self, world_model, latent_dim, action_dim, device="cpu"):
        super().__init__(world_model, device=device)
        self.state_spec = Composite(latent=Unbounded((latent_dim,), device=device), device=device)
        self.observation_spec = Composite(latent=Unbounded((latent_dim,), device=device),
                                          device=device)
        self.action_spec = Bounded(-1.0, 1.0, (action_dim,), device=device)
        self.reward_spec = Unbounded((1,), device=device)

    def _reset(self, tensordict):
        return tensordict.clone()


def torchrl_planner(wm: SimDistWorldModel, cfg: PlannerConfig) -> MPPIPlanner:
    model = WorldModelWrapper(
        TensorDictModule(wm.dynamics, in_keys=["latent", "action"], out_keys=["latent"]),
        TensorDictModule(wm.reward_head, in_keys=["latent", "action"], out_keys=["reward"]))
    env = LatentEnv(model, wm.latent_dim, wm.action_dim, next(wm.parameters()).device)
    value = ValueOperator(wm.value_head, in_keys=["latent"])
    advantage = TDLambdaEstimator(gamma=cfg.gamma, lmbda=0.95, value_network=value)
    return MPPIPlanner(env, advantage, temperature=cfg.temperature,
                       planning_horizon=cfg.horizon, optim_steps=cfg.iterations,
                       num_candidates=cfg.num_samples, top_k=cfg.num_elites)


def latency_ms(fn, calls: int, device: torch.device = torch.device("cpu")) -> float:
    # CUDA work is asynchronous: wait for it on both sides of every timed call
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    fn()
    times = []
    for _ in range(calls):
        sync()
        start = time.perf_counter()
        fn()
        sync()
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--compile", action="store_true")
    parser.add_argument("--batch", type=int, default=1,
                        help="environments planned for at once (the recipe evaluates 32)")
    parser.add_argument("--configs", nargs="+", default=None,
                        help="only these configs (default: all)")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--size", default="small", help="world-model size (tiny, small, wide, paper)")
    parser.add_argument("--latent-dim", type=int, default=None,
                        help="override the size's latent width (the recipe's default: 256)")
    parser.add_argument("--simnorm-groups", type=int, default=None,
                        help="override the size's SimNorm groups (the recipe's default: 32)")
    parser.add_argument("--precision", default="none",
                        help="our planner's PlannerConfig.precision (none, bfloat16); TorchRL's "
                             "planner stays float32")
    args = parser.parse_args()
    torch.manual_seed(0)
    device = torch.device(args.device)
    overrides = {k: v for k, v in (("latent_dim", args.latent_dim),
                                   ("simnorm_groups", args.simnorm_groups)) if v is not None}
    wm = SimDistWorldModel.build(obs_dim=89, action_dim=12, size=args.size,
                                 **overrides).to(device).eval()
    # "recipe H20": the planner of recipes/simdist_quadruped.py's default preset (90% of the
    # samples proposed by the policy prior, scored once per step; TorchRL's planner has no
    # prior, so it samples all 64 at random at the same H x N x iterations); "recipe": the
    # same at the recipe's earlier horizon 10 (the figures in docs/findings.md before
    # 2026-11-27).
    recipe = PlannerConfig(horizon=10, num_samples=64, iterations=3, num_elites=8,
                           policy_fraction=0.9, policy_noise=0.3)
    configs = {"CPU default": PlannerConfig(), "SimDist reference": PlannerConfig.reference(),
               "recipe": recipe, "recipe H20": dataclasses.replace(recipe, horizon=20),
               # command-diverse proposals from three more latents (random here; the policy
               # encodes them), the planner's share of what --planner-proposal-commands costs
               "recipe H20 3 cmds": dataclasses.replace(recipe, horizon=20,
                                                        proposal_commands=(0.25, 0.5, 0.75)),
               # the lambda-return score (--planner-value-lambda 0.95): a value-head call
               # per predicted step, or per k-th step (--planner-value-every k)
               **{f"recipe H20 lambda{f' k{k}' if k > 1 else ''}": dataclasses.replace(
                   recipe, horizon=20, value_lambda=0.95, value_every=k) for k in (1, 2, 4)}}
    print(f"device {device}, torch threads {torch.get_num_threads()}, latent {wm.latent_dim}, "
          f"actions {wm.action_dim}, size {args.size!r}, precision {args.precision!r}")
    print(f"{'config':20s} {'H x N x iters (K)':>20s} {'simdist ms':>11s} {'compiled ms':>12s} "
          f"{'torchrl ms':>11s} {'speed-up':>9s} {'vs first':>9s}")
    if args.configs:
        configs = {k: configs[k] for k in args.configs}
    first_ms = None
    for name, cfg in configs.items():
        calls = 3 if args.quick else (30 if cfg.num_samples < 200 else 8)
        latent = torch.rand(args.batch, wm.latent_dim, device=device)
        ours_cfg = dataclasses.replace(cfg, precision=args.precision)
        ours = LatentMPPIPlanner.from_world_model(wm, ours_cfg, seed=0)
        td = TensorDict({"latent": latent}, [args.batch], device=device)
        if cfg.proposal_commands:
            td["proposal_latent"] = torch.rand(args.batch, len(cfg.proposal_commands),
                                               wm.latent_dim, device=device)
        ours_ms = latency_ms(lambda: ours(td.clone()), calls, device)
        first_ms = first_ms or ours_ms
        compiled_ms = float("nan")
        # The reference config is a GPU config: compiling its 8 x 25 unrolled loop on a
        # 2-core CPU takes far longer than it could ever save, so only the CPU one is.
        if args.compile and (name != "SimDist reference" or device.type == "cuda"):
            compiled = LatentMPPIPlanner.from_world_model(wm, ours_cfg, seed=0, compile=True)
            start = time.perf_counter()
            compiled(td.clone())
            print(f"  ({name}: compile warm-up {time.perf_counter() - start:.0f} s)")
            compiled_ms = latency_ms(lambda: compiled(td.clone()), calls, device)
        theirs = torchrl_planner(wm, cfg).to(device)
        with torch.no_grad():
            theirs_ms = latency_ms(lambda: theirs(td.clone()), max(2, calls // 3), device)
        dims = f"{cfg.horizon} x {cfg.num_samples} x {cfg.iterations} ({cfg.num_elites})"
        print(f"{name:20s} {dims:>20s} {ours_ms:11.1f} {compiled_ms:12.1f} {theirs_ms:11.1f} "
              f"{theirs_ms / ours_ms:8.1f}x {ours_ms / first_ms:8.2f}x")


if __name__ == "__main__":
    main()
