"""Which planner settings turn a pretrained SimDist world model into a good controller?

Loads the pretrained world model of a finished `recipes/simdist_quadruped.py` run
(``--run`` is its output folder) and evaluates, on the recipe's own evaluation seeds, the
policy prior alone (``prior``: the BC head, no planning) and latent MPPI under planner
variants given as ``name:field=value,field=value`` (fields of ``PlannerConfig``). Prints
% of the commanded distance, mean [bootstrap 95% CI] (IQM) per variant and domain.

    python benchmarks/planner_variants.py --run outputs/simdist_quadruped
    python benchmarks/planner_variants.py --run RUN --domains sim slippery_slope \\
        --variant "recipe:" --variant "pi50:policy_fraction=0.5" --variant "std05:init_std=0.5"

The recipe's planner (``recipe:``) is every variant's base; a variant overrides fields.
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
from simdist.recipes import simdist_quadruped as recipe
from simdist.pipelines import locomotion_env, progress_stats, rollout

def parse_variant(text: str) -> tuple[str, dict]:
    name, _, fields = text.partition(":")
    overrides = {}
    for item in filter(None, fields.split(",")):
        key, _, value = item.partition("=")
        overrides[key.strip()] = json.loads(value)
    return name, overrides


def reward_calibration(td) -> dict:
    """Is the planner's model optimistic where it acts? For every step ``t`` with ``H``
    steps after it, the mean reward the planner predicted along the plan it chose
    (``("planner", "rewards")``, ``[B, T, H]``) against the mean reward the env paid over
    steps ``t .. t+H-1``; averaged over envs and steps, and their correlation."""
    predicted = td["planner", "rewards"]
    paid = td["next", "reward"].reshape(predicted.shape[:2])
    horizon, steps = predicted.shape[-1], predicted.shape[1]
    windows = paid.unfold(1, horizon, 1).mean(-1)[:, :steps - horizon]  # [B, T-H]
    planned = predicted[:, :steps - horizon].mean(-1)
    both = torch.stack([planned.flatten(), windows.flatten()])
    return {"predicted": planned.mean().item(), "paid": windows.mean().item(),
            "correlation": torch.corrcoef(both)[0, 1].item()}


class PriorPolicy(torch.nn.Module):
    """The world model's BC policy head on the encoded history (no planning)."""

    def __init__(self, planning_policy):
        super().__init__()
        self.inner = planning_policy

    def forward(self, td):
        td = self.inner(td)  # keeps the history bookkeeping identical to the planner's
        latent = td.get(("planner", "latent"))
        action = self.inner.world_model.policy(latent)
        low, high = self.inner.planner.action_low, self.inner.planner.action_high
        # what was sent, also as the next step's previous action / newest action in flight
        return self.inner.replace_action(td, torch.maximum(torch.minimum(action, high), low))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", required=True, help="a finished recipe output folder")
    parser.add_argument("--domains", nargs="+", default=["sim"])
    parser.add_argument("--variant", action="append", default=None,
                        help="name:field=value,... (PlannerConfig fields); repeatable")
    parser.add_argument("--prior", action="store_true", help="also evaluate the BC prior alone")
    parser.add_argument("--episodes", type=int, default=None, help="default: the run's")
    parser.add_argument("--weights", default=None, help="world-model weights (default: pretrained)")
    parser.add_argument("--calibration", action="store_true",
                        help="also print the planner's predicted reward along its chosen plan "
                             "against the reward the env then paid (see reward_calibration)")
    parser.add_argument("--save-json", default=None,
                        help="write every variant's per-episode fractions per domain here "
                             "(for paired comparisons on the same worlds)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    run = Path(args.run)
    cfg, pretrained = recipe.load_finished_run(
        run, **({"episodes": args.episodes} if args.episodes else {}))
    agent = recipe.load_agent(cfg, pretrained, args.weights)
    variants = [parse_variant(v) for v in (args.variant or ["recipe:"])]
    if args.prior:
        variants = [("prior", None), *variants]
    print(f"run {run} (seed {cfg.seed}), {cfg.episodes} episodes of {cfg.episode_steps} steps")
    print("| variant | domain | % of commanded distance [95% CI] (IQM) | s |")
    print("| --- | --- | --- | --- |")
    saved = {}
    for name, overrides in variants:
        planner = dataclasses.replace(cfg.planner(), **(overrides or {}))
        for domain in args.domains:
            start = time.perf_counter()
            env = locomotion_env(get_target(domain), cfg.episodes, cfg.episode_steps,
                                 cfg.seed + 10_000, task=cfg.task,
                                 primers=[agent.make_primer(planner.latency_compensation)])
            spec = env.action_spec
            policy = agent.policy(spec.space.low[0], spec.space.high[0], planner, seed=cfg.seed)
            if overrides is None:
                policy = PriorPolicy(policy)
            td = rollout(env, policy, cfg.episode_steps)
            stats = progress_stats(td, env.base_env.observation_layout["command"].start)
            env.close()
            saved.setdefault(name, {})[domain] = [float(f) for f in stats["fraction"]]
            if args.save_json:  # rewritten after every evaluation: a killed run keeps its rows
                Path(args.save_json).write_text(json.dumps(saved, indent=1))
            low, high = stats["ci_fraction"]
            extra = ""
            if args.calibration and overrides is not None:
                c = reward_calibration(td)
                extra = (f" predicted {c['predicted']:.3f}, paid {c['paid']:.3f}, "
                         f"corr {c['correlation']:.2f} |")
            print(f"| {name} {overrides or ''} | {domain} | {100 * stats['mean_fraction']:.0f}% "
                  f"[{100 * low:.0f}, {100 * high:.0f}] ({100 * stats['iqm_fraction']:.0f}) | "
                  f"{time.perf_counter() - start:.0f} |{extra}", flush=True)


if __name__ == "__main__":
    main()
