"""Where a target is physically hard: the expert's forward progress over friction x slope.

Evaluates the committed expert (deterministic, 32 episodes of 5 s per cell, seeds 10000+)
on flat-ground quadruped worlds with every geom's friction scaled and the floor tilted,
and prints % of the commanded distance with a bootstrap 95% CI per cell. Used to read the
`slippery_slope` result (README, Results): friction x0.3 is harmless on flat ground and
on 6 degrees but collapses on 12.

    python experiments/expert_friction_slope_grid.py            # ~1 min on 2 cores
    python experiments/expert_friction_slope_grid.py --frictions 1 0.3 --slopes 0 12
    python experiments/expert_friction_slope_grid.py --frictions 1 0.5 0.3 --slopes 0 12 \
        --speeds 0.25 0.5 0.75        # one row per commanded speed instead of a mixture
"""

from __future__ import annotations

import argparse

import simdist  # noqa: F401  (headless GL set-up before dm_control)
import torch

from simdist.envs import TargetDomain
from simdist.experts import Expert
from simdist.pipelines import locomotion_env, progress_stats, rollout


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--expert", default="checkpoints/quadruped_expert/expert.pt")
    parser.add_argument("--frictions", type=float, nargs="+", default=[1.0, 0.6, 0.45, 0.3])
    parser.add_argument("--slopes", type=float, nargs="+", default=[0.0, 6.0, 12.0])
    parser.add_argument("--episodes", type=int, default=32)
    parser.add_argument("--speeds", type=float, nargs="+", default=None,
                        help="evaluate each commanded speed on its own (default: the task's "
                             "speeds, one drawn per episode)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    policy = Expert.load(args.expert).deterministic()
    print("| friction scale | slope (deg) | speed (m/s) | % of commanded distance [95% CI] "
          "| return |")
    print("| --- | --- | --- | --- | --- |")
    # None: the task's own speeds, one drawn per episode (the recipe's evaluation)
    speed_sets = [(s,) for s in args.speeds] if args.speeds else [None]
    for friction in args.frictions:
        for slope in args.slopes:
            target = TargetDomain(name="grid", friction=friction, slope_deg=slope)
            for speeds in speed_sets:
                kwargs = {"speeds": speeds} if speeds else {}
                env = locomotion_env(target, args.episodes, 250, 10_000, **kwargs)
                stats = progress_stats(rollout(env, policy, 250),
                                       env.base_env.observation_layout["command"].start)
                env.close()
                low, high = stats["ci_fraction"]
                speed = f"{speeds[0]:g}" if speeds else "mixed"
                print(f"| {friction:g} | {slope:g} | {speed} | {100 * stats['mean_fraction']:.0f}% "
                      f"[{100 * low:.0f}, {100 * high:.0f}] | {stats['return']:.0f} |",
                      flush=True)


if __name__ == "__main__":
    main()
