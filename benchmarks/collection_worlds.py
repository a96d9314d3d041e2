"""Target-data collection time against how many worlds the planner steps at once.

The recipe collects each round's target data (``budgets_min`` minutes at 50 Hz, 250-step
episodes) with its SimDist planner, ``--collect-episodes`` worlds at a time (default 12).
A planner call's cost grows less than linearly with its batch, so fewer, wider batches
collect the same episodes sooner. This times ``collect_target_data`` of a finished run's
pretrained planner (one model, or the run's ensemble) for the same number of episodes at
each width, each in a fresh process, the first width listed being the reference.

With ``--searches``, the widths are replaced by collection planners at the first width:
each ``SAMPLESxITERATIONSxELITES`` (e.g. ``64x3x8``, the evaluated planner, against
``48x2x6``, the recipe's collection planner since 2026-12-07), the first the reference.

Usage:
    python benchmarks/collection_worlds.py --run OUT/seed_0                  # 12 vs 24
    python benchmarks/collection_worlds.py --run OUT/seed_0 --worlds 12 24 36 --episodes 72
    python benchmarks/collection_worlds.py --run OUT/seed_0 --searches 64x3x8 48x2x6 \
        --episodes 12 --threads 1

Run on quiet cores (wall-clock): anything else running skews every width.
"""

from __future__ import annotations

import argparse
import dataclasses
import subprocess
import sys
import time

import torch


def collect_seconds(run: str, worlds: int, episodes: int, search: str | None = None) -> float:
    """Seconds to collect ``episodes`` target episodes ``worlds`` at a time (this process),
    with the run's collection planner or ``search`` (``SAMPLESxITERATIONSxELITES``)."""
    from simdist.pipelines import simdist as recipe
    cfg, pretrained = recipe.load_finished_run(run)
    cfg = dataclasses.replace(cfg, collect_episodes=worlds)
    if search:
        samples, iterations, elites = map(int, search.split("x"))
        cfg = dataclasses.replace(cfg, collect_planner_samples=samples,
                                  collect_planner_iterations=iterations,
                                  collect_planner_elites=elites)
    agent = recipe.planning_agent(cfg, pretrained)
    start = time.perf_counter()
    data = recipe.collect_target_data(cfg, agent, episodes * cfg.episode_steps, seed=123)
    seconds = time.perf_counter() - start
    if data.shape[0] != episodes:
        raise RuntimeError(f"collected {data.shape[0]} episodes, asked for {episodes}")
    return seconds


def child_seconds(args, worlds: int, search: str | None = None) -> float:
    """:func:`collect_seconds` in a fresh process (no warmed allocator or kernels carried
    over from the previous measurement)."""
    command = [sys.executable, __file__, "--run", args.run, "--episodes", str(args.episodes),
               "--threads", str(args.threads), "--one", str(worlds)]
    out = subprocess.run(command + (["--search", search] if search else []),
                         capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", required=True, help="a finished recipe run (seed folder)")
    parser.add_argument("--worlds", type=int, nargs="+", default=[12, 24],
                        help="worlds per batch; the first is the reference")
    parser.add_argument("--episodes", type=int, default=24, help="episodes collected")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    parser.add_argument("--searches", nargs="+", default=None,
                        help="collection planners SAMPLESxITERATIONSxELITES at the first width")
    parser.add_argument("--one", type=int, default=None, help=argparse.SUPPRESS)
    parser.add_argument("--search", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.one is not None:  # a child: one width, its time on stdout's last line
        print(collect_seconds(args.run, args.one, args.episodes, args.search))
        return
    if args.searches:
        print(f"torch {torch.__version__}, {torch.get_num_threads()} threads; {args.episodes} "
              f"episodes of {args.run}'s pretrained planner, {args.worlds[0]} worlds at once")
        print(f"{'search':>10s} {'seconds':>8s} {'vs first':>9s}")
        reference = None
        for search in args.searches:
            seconds = child_seconds(args, args.worlds[0], search)
            reference = reference or seconds
            print(f"{search:>10s} {seconds:8.1f} {seconds / reference:8.2f}x")
        return
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads; {args.episodes} "
          f"episodes of {args.run}'s pretrained planner")
    print(f"{'worlds at once':>14s} {'batches':>8s} {'seconds':>8s} {'vs first':>9s}")
    reference = None
    for worlds in args.worlds:
        seconds = child_seconds(args, worlds)
        reference = reference or seconds
        batches = -(-args.episodes // worlds)
        print(f"{worlds:14d} {batches:8d} {seconds:8.1f} {seconds / reference:8.2f}x")


if __name__ == "__main__":
    main()
