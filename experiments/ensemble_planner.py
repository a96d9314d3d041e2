"""Does planning with several independently trained world models beat planning with one?

`simulator_dynamics_planner.py --ranking ... --ensemble` measures that the mean of several
models' scores ranks the planner's candidates better than any one of them (their errors
are partly independent). This benchmark asks whether that reaches the return: it plans
with :class:`simdist.modules.WorldModelEnsemble`, K finished SimDist world models side by side (each
encodes the history in its own latent space and rolls its own dynamics; a candidate's
reward, terminal value and the prior's proposal are the members' means), in the recipe's
planner, on the recipe's evaluation worlds of ``--run``, next to each member alone.

    python experiments/ensemble_planner.py --run RUN --domains slippery_slope \\
        --members RUN/stages/round_4/simdist.pt OTHER/stages/round_4/simdist.pt ...

``--chain OUT`` runs SimDist's target rounds with the ensemble instead: the ensemble's
planner collects the round's target data (the recipe's budgets and collection seeds),
each member's dynamics alone is finetuned on all data so far (the recipe's
``finetune_updates``, loss, lr and batch), and the ensemble is evaluated in the target:

    python experiments/ensemble_planner.py --run RUN --chain OUT \\
        --members pretrained OTHER1/stages/pretrain/world_model.pt OTHER2/...

``--pessimism 0 1`` also scores candidates by a lower confidence bound (the members' mean
reward and value minus that many standard deviations over members).

The members must share the run's model config (size, history). Costs K x one model's
planner time (and K x its finetuning updates).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import simdist  # noqa: F401  (headless GL set-up before dm_control)
import torch

from simdist.agents import SimDistAgent
from simdist.envs import get_target
from simdist.modules import WorldModelEnsemble
from simdist.pipelines import as_slices, episode_stats, locomotion_env, rollout
from simdist.pipelines import train_resumable
from simdist.pipelines import simdist as recipe
from simdist.utils import load_memmap, save_memmap


def evaluate(cfg, world_model, domain: str, name: str) -> str:
    agent = SimDistAgent(world_model, planner_config=cfg.planner())
    env = locomotion_env(get_target(domain), cfg.episodes, cfg.episode_steps,
                         cfg.seed + 10_000, task=cfg.task,
                         primers=[agent.make_primer(cfg.planner().latency_compensation)])
    spec = env.action_spec
    policy = agent.policy(spec.space.low[0], spec.space.high[0], cfg.planner(), seed=cfg.seed)
    start = time.perf_counter()
    td = rollout(env, policy, cfg.episode_steps, desc=f"{name} in {domain}")
    stats = episode_stats(td, env.base_env.observation_layout)
    env.close()
    low, high = stats["ci_fraction"]
    return (f"| {name} | {domain} | {100 * stats['mean_fraction']:.0f}% [{100 * low:.0f}, "
            f"{100 * high:.0f}] ({100 * stats['iqm_fraction']:.0f}) | "
            f"{time.perf_counter() - start:.0f} |")


def chain(cfg, agents: list, out: Path) -> None:
    """SimDist's rounds with the ensemble planner collecting and every member finetuned."""
    members = [a.world_model for a in agents]
    ensemble = SimDistAgent(WorldModelEnsemble(members), planner_config=cfg.planner())
    stats = recipe.evaluate_planner(cfg, ensemble, cfg.target)[0]
    rows = [(0.0, stats)]
    data, done = [], 0
    for k, minutes in enumerate(cfg.budgets_min):
        budget = round(minutes * recipe.STEPS_PER_MINUTE)
        folder = out / f"round_{k + 1}" / "data"
        if not folder.exists():
            save_memmap(recipe.collect_target_data(cfg, ensemble, budget - done,
                                                   seed=cfg.seed + 1000 * (k + 1)), folder)
        data.append(load_memmap(folder))
        done = sum(d.numel() for d in data)
        buffer = as_slices(torch.cat(data, 0), cfg.slice_len, cfg.batch_slices)
        for i, agent in enumerate(agents):
            # a fresh optimiser per round, as the recipe's (it reloads the agent each round)
            optim = torch.optim.Adam(agent.finetune_loss.trainable_parameters(),
                                     lr=agent.config.finetune_lr)
            agent.finetune_optim = optim
            train_resumable(agent.finetune_update,
                            lambda: buffer.sample().reshape(-1, cfg.slice_len),
                            cfg.finetune_updates, {"wm": agent.world_model, "opt": optim},
                            out / f"round_{k + 1}" / f"member_{i}.ckpt",
                            desc=f"round {k + 1}: finetune member {i} dynamics",
                            seed=cfg.seed + 100 * k + i)
        stats = recipe.evaluate_planner(cfg, ensemble, cfg.target)[0]
        rows.append((minutes, stats))
        low, high = stats["ci_fraction"]
        print(f"| ensemble of {len(members)} | {minutes:g} min ({done} steps) | "
              f"{100 * stats['mean_fraction']:.0f}% [{100 * low:.0f}, {100 * high:.0f}] "
              f"({100 * stats['iqm_fraction']:.0f}) |", flush=True)
    (out / "chain.json").write_text(json.dumps(
        [{"minutes": m, **{k: v for k, v in s.items() if isinstance(v, (int, float, list))}}
         for m, s in rows], indent=1))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", required=True, help="a finished recipe run (config, worlds)")
    parser.add_argument("--members", nargs="+", required=True,
                        help="world-model weights (or 'pretrained': the run's own)")
    parser.add_argument("--domains", nargs="+", default=["slippery_slope"])
    parser.add_argument("--episodes", type=int, default=None, help="default: the run's")
    parser.add_argument("--alone", action="store_true", help="also evaluate each member alone")
    parser.add_argument("--chain", default=None, metavar="OUT",
                        help="run SimDist's target rounds with the ensemble (see above)")
    parser.add_argument("--pessimism", type=float, nargs="+", default=[0.0],
                        help="evaluate the ensemble scoring mean - this x the members' std "
                             "of reward and value (one row per value; not with --chain)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    cfg, pretrained = recipe.load_finished_run(
        args.run, **({"episodes": args.episodes} if args.episodes else {}))
    agents = [recipe.load_agent(cfg, pretrained, None if m == "pretrained" else m)
              for m in args.members]
    members = [a.world_model for a in agents]
    if args.chain:
        chain(cfg, agents, Path(args.chain))
        return
    print(f"run {args.run} (seed {cfg.seed}), {cfg.episodes} episodes, recipe planner")
    print("| planner's model | domain | % of commanded distance [95% CI] (IQM) | s |")
    print("| --- | --- | --- | --- |")
    for domain in args.domains:
        for lam in args.pessimism:
            name = f"ensemble of {len(members)}" + (f", pessimism {lam:g}" if lam else "")
            print(evaluate(cfg, WorldModelEnsemble(members, pessimism=lam), domain, name),
                  flush=True)
        if args.alone:
            for path, member in zip(args.members, members):
                print(evaluate(cfg, member, domain, path), flush=True)


if __name__ == "__main__":
    main()
