"""How far could dynamics-only finetuning take the planner? Plan with the simulator itself.

SimDist finetunes only the dynamics; the encoder, reward, value and policy-prior heads stay
as pretrained. The best a perfect finetune could do is therefore the same planner
(:class:`~simdist.modules.LatentMPPIPlanner`, same config, same heads) with the *true*
target dynamics in place of the learned ones. This benchmark builds exactly that: a
candidate's "latent" is the simulator state of its own copy of the world plus its
observation history; stepping it runs MuJoCo in the target domain; the reward, terminal
value and prior proposals are the pretrained heads on the encoded history.

    python experiments/simulator_dynamics_planner.py --run RUN --domains slippery_slope
    python experiments/simulator_dynamics_planner.py --run RUN --domains sim slippery_slope \\
        --episodes 16 --variant recipe: --variant "H20:horizon=20"
    python experiments/simulator_dynamics_planner.py --run RUN --episodes 8 \\
        --ranking finetuned=RUN/stages/round_4/simdist.pt pretrained=pretrained

Compare with ``experiments/planner_variants.py --run RUN`` (the learned dynamics, pretrained
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
from simdist.pipelines import episode_stats, locomotion_env, rollout
from simdist.pipelines import SimulatorPlanningPolicy
from simdist.pipelines import simdist as recipe
from simdist.utils import save_memmap, write_json_atomic


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
    parser.add_argument("--ranking", nargs="+", default=None, metavar="NAME=WEIGHTS",
                        help="instead of evaluating: how well each world model (NAME=path of "
                             "its weights, or NAME=pretrained) ranks candidate plans against "
                             "the simulator (see ranking())")
    parser.add_argument("--ensemble", action="append", default=[], metavar="NAME=A+B+...",
                        help="with --ranking: also rank by the mean of the named models' "
                             "scores, each standardised per state (a score-level ensemble of "
                             "independently trained models); repeatable")
    parser.add_argument("--ranking-noise", type=float, default=0.3,
                        help="std of the candidates around the plan (the prior's noise)")
    parser.add_argument("--save-rollouts", default=None, metavar="DIR",
                        help="write each rollout (the recipe's target-data keys) to "
                             "DIR/<variant>_<domain> as a memmap folder")
    parser.add_argument("--save-json", default=None, metavar="FILE",
                        help="also write every evaluation's statistics, per-episode "
                             "fractions included, to FILE (to pool seeds or pair variants)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    run = Path(args.run)
    cfg, pretrained = recipe.load_finished_run(
        run, episodes=args.episodes, **({"episode_steps": args.steps} if args.steps else {}))
    agent = recipe.load_agent(cfg, pretrained)
    if args.ranking:
        for domain in args.domains:
            ranking(cfg, pretrained, dict(item.split("=", 1) for item in args.ranking), domain,
                    args.ranking_noise, args.episodes, args.env_seed,
                    ensembles={k: v.split("+") for k, v in
                               (item.split("=", 1) for item in args.ensemble)})
        return
    variants = [parse_variant(v) for v in (args.variant or ["recipe:"])]
    print(f"run {run} (seed {cfg.seed}), {cfg.episodes} episodes of {cfg.episode_steps} "
          "steps, simulator dynamics + pretrained heads")
    print("| variant | domain | % of commanded distance [95% CI] (IQM), on its back | s |")
    print("| --- | --- | --- | --- |")
    saved = {}
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
            stats = episode_stats(td, env.base_env.observation_layout)
            env.close()
            if args.save_rollouts:
                save_memmap(td.select(*recipe.TARGET_KEYS, ("next", "forward_progress")),
                            Path(args.save_rollouts) / f"{name}_{domain}")
            low, high = stats["ci_fraction"]
            print(f"| {name} {overrides or ''} | {domain} | {100 * stats['mean_fraction']:.0f}% "
                  f"[{100 * low:.0f}, {100 * high:.0f}] ({100 * stats['iqm_fraction']:.0f}), "
                  f"{sum(stats['upside_down'])}/{len(stats['fraction'])} on its back | "
                  f"{time.perf_counter() - start:.0f} |", flush=True)
            if args.save_json:  # rewritten after each evaluation: a killed run keeps the rest
                saved.setdefault(name, {})[domain] = {"overrides": overrides, **stats}
                write_json_atomic(Path(args.save_json), saved)


def ranking(cfg, pretrained: dict, weights: dict, domain: str, noise: float, worlds: int,
            env_seed: int | None, checkpoints=range(19, 200, 20), candidates: int = 64,
            ensembles: dict[str, list[str]] | None = None):
    """Does a learned model rank the planner's candidates as the true dynamics do?

    The first model's planner drives ``worlds`` episodes; every 20 steps, ``candidates``
    action sequences (its plan + Gaussian ``noise``, the prior's trust region) are scored
    by the simulator (:class:`SimulatorPlanningPolicy`'s planner, same heads) and by each
    model (same score: discounted predicted rewards + terminal value). Prints the mean
    Spearman correlation of the two scores per state, and where the model's best
    candidate lies on the true scale: 0 = the candidates' mean, 1 = the truly best.
    ``ensembles`` maps a name to models of ``weights`` whose scores, standardised per
    state (each model's scale differs), are averaged and ranked the same way: if the
    models' errors are independent, the mean ranks better than any member.
    """
    from scipy import stats
    from torchrl.envs.utils import step_mdp
    from simdist.modules import LatentMPPIPlanner

    agents = {k: recipe.load_agent(cfg, pretrained, None if v == "pretrained" else v)
              for k, v in weights.items()}
    first = next(iter(agents.values()))
    # every model scores from the driver's (the first model's) history windows
    window = lambda a: (a.world_model.encoder.history, a.world_model.encoder.input_dim)  # noqa: E731
    misfits = sorted(k for k, a in agents.items() if window(a) != window(first))
    if misfits:
        raise SystemExit(f"--ranking: {misfits} read other history windows (steps, width) "
                         f"than the first model's {window(first)}")
    env = locomotion_env(get_target(domain), worlds, cfg.episode_steps,
                         cfg.seed + 20_000 if env_seed is None else env_seed, task=cfg.task,
                         primers=[first.make_primer(0)])
    low, high = env.action_spec.space.low[0], env.action_spec.space.high[0]
    driver = first.policy(low, high, cfg.planner(), seed=cfg.seed)
    truth = SimulatorPlanningPolicy(first, env.base_env.sims, cfg.planner(), low, high, cfg.seed)
    planners = {k: LatentMPPIPlanner.from_world_model(a.world_model, cfg.planner())
                for k, a in agents.items()}
    generator = torch.Generator().manual_seed(cfg.seed)
    ensembles = ensembles or {}
    unknown = {m for members in ensembles.values() for m in members} - set(agents)
    if unknown:
        raise ValueError(f"--ensemble names models not in --ranking: {sorted(unknown)}")
    rho = {k: [] for k in [*agents, *ensembles]}
    pick = {k: [] for k in rho}
    speed = []  # each state's commanded speed, for the table per speed
    command = env.base_env.observation_layout["command"].start
    td = env.reset()
    with torch.no_grad():
        for t in range(max(checkpoints) + 1):
            td = driver(td)
            if t in checkpoints:
                history, mean = td["next", "simdist", "history"], td["planner", "mean"]
                actions = mean[:, None] + noise * torch.randn(worlds, candidates, *mean.shape[1:],
                                                              generator=generator)
                actions = torch.maximum(torch.minimum(actions, high), low)
                truth.dynamics.sync()
                true = truth.planner._evaluate(truth.dynamics.latent(history),
                                               actions.double())[0].float()
                scores = {}
                for k, agent in agents.items():
                    latent = agent.world_model.encode(history).reshape(worlds, -1)
                    scores[k] = planners[k]._evaluate(latent, actions)[0]
                for k, members in ensembles.items():
                    scores[k] = torch.stack([standardise(scores[m]) for m in members]).mean(0)
                speed += td["observation"][:, command].tolist()
                for k, predicted in scores.items():
                    for b in range(worlds):
                        rho[k].append(stats.spearmanr(true[b], predicted[b]).statistic)
                        best = true[b, predicted[b].argmax()]
                        span = (true[b].max() - true[b].mean()).clamp_min(1e-9)
                        pick[k].append(((best - true[b].mean()) / span).item())
            td = step_mdp(env.step(td), keep_other=True)
    env.close()
    print("| model | domain | Spearman (true vs predicted score) | model's pick (0 mean, 1 best) |")
    print("| --- | --- | --- | --- |")
    speed = torch.tensor(speed).round(decimals=6)
    for k in rho:
        r, q = torch.tensor(rho[k]), torch.tensor(pick[k])
        rows = [(domain, torch.ones_like(speed, dtype=torch.bool))]
        rows += [(f"{domain}, {s:g} m/s", speed == s) for s in sorted(set(speed.tolist()))]
        for where, chosen in rows:
            rs, qs = r[chosen], q[chosen]
            print(f"| {k} | {where} | {rs.nanmean():.2f} +- {rs[~rs.isnan()].std():.2f} | "
                  f"{qs.mean():.2f} +- {qs.std():.2f} (n={len(qs)}) |", flush=True)


def standardise(scores: torch.Tensor) -> torch.Tensor:
    """Per-state z-scores of candidate scores ``[worlds, candidates]``."""
    return (scores - scores.mean(-1, keepdim=True)) / scores.std(-1, keepdim=True).clamp_min(1e-9)


def parse_variant(text: str) -> tuple[str, dict]:
    name, _, fields = text.partition(":")
    return name, {k.strip(): json.loads(v) for k, _, v in
                  (item.partition("=") for item in filter(None, fields.split(",")))}


if __name__ == "__main__":
    main()
