"""Pretraining's slice sampling: how the recipe's dataset buffer is built, against the update.

The SimDist recipe pretrains on slices sampled from the memory-mapped dataset
(``load_dataset``: TorchRL's ``SliceSampler`` over a ``TensorStorage``). This times one
``buffer.sample()`` of a finished run's dataset three ways, interleaved round by round:

- ``every entry, boundaries rescanned``: the buffer as the recipe built it until
  2026-12-07 (``SliceSampler`` without ``cache_values``; the sampler scans the episode id
  of every row at each sample);
- ``every entry, boundaries cached``: ``cache_values=True`` (the storage never changes);
- ``the loss's entries, cached``: the recipe's buffer now (``pretraining_buffer``),

and one pretraining update of the run's own model on such a batch, for scale. The first
way is the reference of the ratio column. All three draw the same slices (checked here).

Usage:
    python benchmarks/pretraining_sampling.py --run OUT/seed_0      # a finished recipe run
    python benchmarks/pretraining_sampling.py --run OUT/seed_0 --rounds 5 --samples 100

Run on quiet cores (wall-clock): anything else running skews every row.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

import torch
from torchrl.data import SliceSampler, TensorDictReplayBuffer, TensorStorage

from simdist.data import load_dataset
from simdist.data.dataset import read_dataset_meta
from simdist.objectives.simdist_pretrain import SimDistPretrainLoss
from simdist.utils import load_memmap
from simdist.utils.stages import read_stage_record


def rescanning_buffer(path: str, slice_len: int, batch: int) -> TensorDictReplayBuffer:
    """The recipe's buffer before 2026-12-07: every entry, boundaries found per sample."""
    meta = read_dataset_meta(path)
    data = load_memmap(f"{path}/data", manifest=meta["files"]).reshape(-1)
    sampler = SliceSampler(slice_len=slice_len, traj_key="episode", strict_length=True)
    return TensorDictReplayBuffer(storage=TensorStorage(data), sampler=sampler,
                                  batch_size=batch)


def time_samples(buffer, samples: int, seed: int) -> tuple[float, list]:
    """Median milliseconds per ``buffer.sample()`` and the batches drawn from ``seed``."""
    torch.manual_seed(seed)
    times, batches = [], []
    for _ in range(samples):
        start = time.perf_counter()
        batches.append(buffer.sample())
        times.append(time.perf_counter() - start)
    return 1000 * statistics.median(times), batches


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", required=True, help="a finished recipe run (seed folder)")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds")
    parser.add_argument("--samples", type=int, default=60, help="samples per way and round")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    from simdist.pipelines import simdist as recipe
    cfg, pretrained = recipe.load_finished_run(args.run)
    path = read_stage_record(args.run, "dataset")["result"]["path"]
    batch = cfg.slice_len * cfg.batch_slices
    keys = dataclasses.astuple(SimDistPretrainLoss.default_keys())
    ways = {"every entry, boundaries rescanned": lambda: rescanning_buffer(path, cfg.slice_len,
                                                                            batch),
            "every entry, boundaries cached": lambda: load_dataset(path, cfg.slice_len, batch),
            "the loss's entries, cached": lambda: recipe.pretraining_buffer(cfg, path)}
    buffers = {name: make() for name, make in ways.items()}
    times: dict[str, list[float]] = {name: [] for name in ways}
    for r in range(args.rounds):
        drawn = {}
        for name, buffer in buffers.items():
            ms, drawn[name] = time_samples(buffer, args.samples, seed=r)
            times[name].append(ms)
        first = list(drawn.values())
        for other in first[1:]:
            if not all((a.select(*keys) == b.select(*keys)).all() for a, b in zip(first[0], other)):
                raise RuntimeError("the ways drew different slices")
    agent = recipe.load_agent(cfg, pretrained)
    sample = buffers["the loss's entries, cached"].sample().reshape(-1, cfg.slice_len)
    agent.pretrain_update(sample)  # warm-up
    update = []
    for _ in range(20):
        start = time.perf_counter()
        agent.pretrain_update(sample)
        update.append(time.perf_counter() - start)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads; {path}: "
          f"{cfg.batch_slices} slices of {cfg.slice_len} steps per sample; medians of "
          f"{args.samples} samples per round, {args.rounds} rounds (per-round medians)")
    reference = statistics.median(times[next(iter(ways))])
    print(f"{'buffer':<36s} {'ms per sample':>14s} {'vs first':>9s}   rounds")
    for name, t in times.items():
        ms = statistics.median(t)
        print(f"{name:<36s} {ms:14.1f} {reference / ms:8.2f}x   "
              + " ".join(f"{x:.1f}" for x in t))
    print(f"{'one pretraining update (the run model)':<36s} "
          f"{1000 * statistics.median(update):14.1f}")


if __name__ == "__main__":
    main()
