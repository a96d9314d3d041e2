"""Does planning with several independently trained world models beat planning with one?

`simulator_dynamics_planner.py --ranking ... --ensemble` measures that the mean of several
models' scores ranks the planner's candidates better than any one of them (their errors
are partly independent). This benchmark asks whether that reaches the return: it plans
with :class:`WorldModelEnsemble`, K finished SimDist world models side by side (each
encodes the history in its own latent space and rolls its own dynamics; a candidate's
reward, terminal value and the prior's proposal are the members' means), in the recipe's
planner, on the recipe's evaluation worlds of ``--run``, next to each member alone.

    python benchmarks/ensemble_planner.py --run RUN --domains slippery_slope \\
        --members RUN/stages/round_4/simdist.pt OTHER/stages/round_4/simdist.pt ...

The members must share the run's model config (size, history). Costs K x one model's
planner time.
"""

from __future__ import annotations

import argparse
import time

import simdist  # noqa: F401  (headless GL set-up before dm_control)
import torch
from torch import nn

from simdist.agents import SimDistAgent
from simdist.envs import get_target
from simdist.pipelines import locomotion_env, progress_stats, rollout
from simdist.recipes import simdist_quadruped as recipe


class _Split(nn.Module):
    """Applies member ``i``'s part to its slice of a concatenated latent."""

    def __init__(self, parts, latent_dim: int, reduce: str):
        super().__init__()
        self.parts, self.latent_dim, self.reduce = nn.ModuleList(parts), latent_dim, reduce

    def forward(self, latent, *rest):
        chunks = latent.split(self.latent_dim, -1)
        if len(chunks) != len(self.parts):
            raise ValueError(f"latent of size {latent.shape[-1]} is not {len(self.parts)} "
                             f"members x {self.latent_dim}")
        outs = [part(z, *rest) for part, z in zip(self.parts, chunks)]
        return torch.cat(outs, -1) if self.reduce == "cat" else torch.stack(outs).mean(0)


class _Encoders(_Split):
    def __init__(self, encoders, latent_dim: int):
        super().__init__(encoders, latent_dim, "cat")
        self.history, self.obs_dim = encoders[0].history, encoders[0].obs_dim

    def forward(self, window):
        return torch.cat([enc(window) for enc in self.parts], -1)


class WorldModelEnsemble(nn.Module):
    """K SimDist world models as one: concatenated latents, mean reward/value/prior.

    Has the verbs and parts :class:`~simdist.modules.LatentMPPIPlanner.from_world_model`
    and :class:`~simdist.agents.SimDistPolicy` use, so the recipe's planner runs on it
    unchanged.
    """

    def __init__(self, members):
        super().__init__()
        first = members[0]
        if any(m.latent_dim != first.latent_dim or m.encoder.history != first.encoder.history
               for m in members):
            raise ValueError("ensemble members must share latent size and history")
        L = first.latent_dim
        self.members = nn.ModuleList(members)
        self.encoder = _Encoders([m.encoder for m in members], L)
        self.dynamics = _Split([m.dynamics for m in members], L, "cat")
        self.reward_head = _Split([m.reward_head for m in members], L, "mean")
        self.value_head = _Split([m.value_head for m in members], L, "mean")
        self.policy_head = _Split([m.policy_head for m in members], L, "mean")
        self.latent_dim, self.action_dim = L * len(members), first.action_dim

    def encode(self, window):
        return self.encoder(window)

    def rollout(self, latent, actions):
        out = []
        for i in range(actions.shape[-2]):
            latent = self.dynamics(latent, actions[..., i, :])
            out.append(latent)
        return torch.stack(out, -2)


def evaluate(cfg, world_model, domain: str, name: str) -> str:
    agent = SimDistAgent(world_model, planner_config=cfg.planner())
    env = locomotion_env(get_target(domain), cfg.episodes, cfg.episode_steps,
                         cfg.seed + 10_000, task=cfg.task,
                         primers=[agent.make_primer(cfg.planner().latency_compensation)])
    spec = env.action_spec
    policy = agent.policy(spec.space.low[0], spec.space.high[0], cfg.planner(), seed=cfg.seed)
    start = time.perf_counter()
    td = rollout(env, policy, cfg.episode_steps, desc=f"{name} in {domain}")
    stats = progress_stats(td, env.base_env.observation_layout["command"].start)
    env.close()
    low, high = stats["ci_fraction"]
    return (f"| {name} | {domain} | {100 * stats['mean_fraction']:.0f}% [{100 * low:.0f}, "
            f"{100 * high:.0f}] ({100 * stats['iqm_fraction']:.0f}) | "
            f"{time.perf_counter() - start:.0f} |")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", required=True, help="a finished recipe run (config, worlds)")
    parser.add_argument("--members", nargs="+", required=True,
                        help="world-model weights (or 'pretrained': the run's own)")
    parser.add_argument("--domains", nargs="+", default=["slippery_slope"])
    parser.add_argument("--episodes", type=int, default=None, help="default: the run's")
    parser.add_argument("--alone", action="store_true", help="also evaluate each member alone")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    cfg, pretrained = recipe.load_finished_run(
        args.run, **({"episodes": args.episodes} if args.episodes else {}))
    members = [recipe.load_agent(cfg, pretrained, None if m == "pretrained" else m).world_model
               for m in args.members]
    print(f"run {args.run} (seed {cfg.seed}), {cfg.episodes} episodes, recipe planner")
    print("| planner's model | domain | % of commanded distance [95% CI] (IQM) | s |")
    print("| --- | --- | --- | --- |")
    for domain in args.domains:
        print(evaluate(cfg, WorldModelEnsemble(members), domain, f"ensemble of {len(members)}"),
              flush=True)
        if args.alone:
            for path, member in zip(args.members, members):
                print(evaluate(cfg, member, domain, path), flush=True)


if __name__ == "__main__":
    main()
