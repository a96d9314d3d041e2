"""How far could dynamics-only finetuning take the planner? Plan with the simulator itself.

SimDist finetunes only the dynamics; the encoder, reward, value and policy-prior heads stay
as pretrained. The best a perfect finetune could do is therefore the same planner
(:class:`~simdist.modules.LatentMPPIPlanner`, same config, same heads) with the *true*
target dynamics in place of the learned ones. This benchmark builds exactly that: a
candidate's "latent" is the simulator state of its own copy of the world plus its
observation history; stepping it runs MuJoCo in the target domain; the reward, terminal
value and prior proposals are the pretrained heads on the encoded history.

    python benchmarks/simulator_dynamics_planner.py --run RUN --domains slippery_slope
    python benchmarks/simulator_dynamics_planner.py --run RUN --domains sim slippery_slope \\
        --episodes 16 --variant recipe: --variant "H20:horizon=20"

Compare with ``benchmarks/planner_variants.py --run RUN`` (the learned dynamics, pretrained
or ``--weights`` of a finetuning round) on the same seeds. Costs ~B x (proposals +
iterations x random samples) x H MuJoCo steps per control step: minutes per episode batch
on one core. Targets with action latency are refused (the copies would need the delay
line's contents; the recipe's latency compensation is not modelled here).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import simdist  # noqa: F401  (headless GL set-up before dm_control)
import torch

from simdist.envs import get_target
from simdist.pipelines import locomotion_env, progress_stats, rollout
from simdist.pipelines import SimulatorPlanningPolicy
from simdist.recipes import simdist_quadruped as recipe
from simdist.utils import save_memmap


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", required=True, help="a finished recipe output folder")
    parser.add_argument("--domains", nargs="+", default=["slippery_slope"])
    parser.add_argument("--variant", action="append", default=None,
                        help="name:field=value,... (PlannerConfig fields); repeatable")
    parser.add_argument("--episodes", type=int, default=16)
    parser.add_argument("--steps", type=int, default=None, help="episode steps (default: the run's)")
    parser.add_argument("--env-seed", type=int, default=None,
                        help="seed of the evaluation worlds (default: the recipe's, seed + 10000)")
    parser.add_argument("--save-rollouts", default=None, metavar="DIR",
                        help="write each rollout (the recipe's target-data keys) to "
                             "DIR/<variant>_<domain> as a memmap folder")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    run = Path(args.run)
    cfg_dict = json.loads((run / "config.json").read_text())
    cfg_dict = cfg_dict.get("config", cfg_dict)
    fields = {f.name for f in dataclasses.fields(recipe.Config)}
    cfg = recipe.Config(**{k: v for k, v in cfg_dict.items() if k in fields})
    cfg = dataclasses.replace(cfg, episodes=args.episodes, **({"episode_steps": args.steps} if args.steps else {}))
    pretrained = json.loads((run / "stages" / "pretrain.json").read_text())["result"]
    agent = recipe.load_agent(cfg, pretrained)
    variants = [parse_variant(v) for v in (args.variant or ["recipe:"])]
    print(f"run {run} (seed {cfg.seed}), {cfg.episodes} episodes of {cfg.episode_steps} "
          "steps, simulator dynamics + pretrained heads")
    print("| variant | domain | % of commanded distance [95% CI] (IQM) | s |")
    print("| --- | --- | --- | --- |")
    for name, overrides in variants:
        planner = dataclasses.replace(cfg.planner(), **overrides)
        for domain in args.domains:
            start = time.perf_counter()
            env = locomotion_env(get_target(domain), cfg.episodes, cfg.episode_steps,
                                 cfg.seed + 10_000 if args.env_seed is None else args.env_seed,
                                 task=cfg.task, primers=[agent.make_primer(0)])
            spec = env.action_spec
            policy = SimulatorPlanningPolicy(agent, env.base_env.sims, planner,
                                             spec.space.low[0], spec.space.high[0], cfg.seed)
            td = rollout(env, policy, cfg.episode_steps, desc=f"{name} in {domain}")
            stats = progress_stats(td, env.base_env.observation_layout["command"].start)
            env.close()
            if args.save_rollouts:
                save_memmap(td.select(*recipe.TARGET_KEYS, ("next", "forward_progress")),
                            Path(args.save_rollouts) / f"{name}_{domain}")
            low, high = stats["ci_fraction"]
            print(f"| {name} {overrides or ''} | {domain} | {100 * stats['mean_fraction']:.0f}% "
                  f"[{100 * low:.0f}, {100 * high:.0f}] ({100 * stats['iqm_fraction']:.0f}) | "
                  f"{time.perf_counter() - start:.0f} |", flush=True)


def parse_variant(text: str) -> tuple[str, dict]:
    name, _, fields = text.partition(":")
    return name, {k.strip(): json.loads(v) for k, _, v in
                  (item.partition("=") for item in filter(None, fields.split(",")))}


if __name__ == "__main__":
    main()
