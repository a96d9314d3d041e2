"""The SimDist recipe's dataset stage in one process against shards made side by side.

Times ``generate_dataset`` on the recipe's dataset settings (its default expert and
snapshots, 32-world shards of 250 steps) for ``--shards`` shards three ways, in turn:

- ``one process``: ``jobs=1``, one TorchRL collector over every shard, torch's threads
  (the recipe until 2026-12-07; the reference of the ratio column);
- ``side by side, a shard per call``: ``jobs`` one-thread workers, each call one
  ``generate_shard`` (a collector and its batched worlds built per shard);
- ``side by side, runs of shards``: ``generate_dataset(jobs=...)`` as the recipe calls it
  now, each call a run of consecutive shards with one collector.

Each way writes its own folder; the three datasets are checked to be the same bytes. The
workers are started (and kept, as ``run_jobs`` keeps them) before the clocks start; their
start-up, paid once per run in the recipe, is timed on its own and printed.

Usage:
    python benchmarks/dataset_jobs.py                 # 12 shards (384 episodes)
    python benchmarks/dataset_jobs.py --shards 48     # the recipe's whole dataset

Run on quiet cores (wall-clock).
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time

import torch

from simdist.data import generate_dataset, generate_shard
from simdist.utils import iter_jobs, load_memmap


def _nothing() -> None:
    return None


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shards", type=int, default=12, help="32-episode shards")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes")
    args = parser.parse_args()
    from simdist.experts import resolve_expert
    from simdist.pipelines import simdist as recipe
    cfg = recipe.Config()
    data_cfg = dataclasses.replace(recipe.dataset_config(cfg),
                                   episodes=args.shards * cfg.dataset_shard_episodes)
    experts = recipe.load_experts(str(resolve_expert(cfg.expert)))
    start = time.perf_counter()
    list(iter_jobs([(_nothing, ())] * args.jobs, args.jobs, threads=1))
    startup = time.perf_counter() - start
    out = tempfile.mkdtemp(prefix="dataset_jobs_")
    seconds, folders = {}, {}

    def per_shard(folder):
        calls = [(generate_shard, (data_cfg, s, *experts)) for s in range(data_cfg.shards)]
        rows = dict(iter_jobs(calls, args.jobs, threads=1))
        return torch.cat([rows[i] for i in range(len(calls))], 0)

    ways = {
        "one process": lambda f: load_memmap(generate_dataset(
            data_cfg, f, *experts, progress=False) / "data"),
        "side by side, a shard per call": per_shard,
        "side by side, runs of shards": lambda f: load_memmap(generate_dataset(
            data_cfg, f, *experts, progress=False, jobs=args.jobs, threads=1) / "data"),
    }
    for name, way in ways.items():
        start = time.perf_counter()
        folders[name] = way(f"{out}/{len(folders)}")
        seconds[name] = time.perf_counter() - start
    first = list(folders.values())[0]
    same = all((first == other).all() for other in list(folders.values())[1:])
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads in this process; "
          f"{args.shards} shards of {data_cfg.shard_episodes} episodes x "
          f"{data_cfg.episode_steps} steps; {args.jobs} one-thread workers (start-up, once: "
          f"{startup:.1f} s); the same bytes every way: {same}")
    reference = seconds["one process"]
    print(f"{'way':<34s} {'seconds':>8s} {'vs first':>9s}")
    for name, s in seconds.items():
        print(f"{name:<34s} {s:8.1f} {reference / s:8.2f}x")
    if not same:
        raise SystemExit("the ways made different datasets")


if __name__ == "__main__":
    main()
