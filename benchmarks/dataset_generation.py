"""Dataset generation throughput vs a raw dm_control loop, in the same run.

"simdist" = one shard of perturbed-expert episodes exactly as ``generate_dataset`` makes
them: batched quadruped env, episode mixture of two 256-wide SAC actors, perturbation
schedule, critic value labels, and the write into a memory-mapped dataset. "raw" = a
``dm_control.suite`` quadruped loop with zero actions and no policy, no storage.

Usage:
    python benchmarks/dataset_generation.py           # ~2 minutes
    python benchmarks/dataset_generation.py --pixels  # adds a 64x64 pixel shard
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np
import torch
from dm_control import suite

import simdist  # noqa: F401
from simdist.data import DatasetConfig, generate_dataset
from simdist.experts import Expert


def raw_rate(steps: int) -> float:
    env = suite.load("quadruped", "walk", task_kwargs={"random": 0})
    env.reset()
    action = np.zeros(env.action_spec().shape)
    start = time.perf_counter()
    for _ in range(steps):
        if env.step(action).last():
            env.reset()
    return steps / (time.perf_counter() - start)


def simdist_rate(cfg: DatasetConfig) -> tuple[float, float]:
    torch.manual_seed(0)
    experts = (Expert.untrained(89, 12), [Expert.untrained(89, 12)])
    with tempfile.TemporaryDirectory() as out:
        start = time.perf_counter()
        path = generate_dataset(cfg, out, *experts, progress=False)
        elapsed = time.perf_counter() - start
        import json
        meta = json.loads((path / "meta.json").read_text())
    return meta["transitions"] / elapsed, meta["bytes"] / meta["transitions"] * 1e6


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pixels", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(1)
    state_cfg = DatasetConfig(episodes=64, shard_episodes=16, episode_steps=250)
    raw_before = raw_rate(3000)
    ours, bytes_per_m = simdist_rate(state_cfg)
    raw_after = raw_rate(3000)
    raw = (raw_before + raw_after) / 2
    print(f"raw dm_control quadruped loop      {raw:8.0f} steps/s")
    print(f"simdist dataset generation (state) {ours:8.0f} transitions/s  "
          f"{ours / raw:.2f}x raw   {bytes_per_m / 1e9:.2f} GB per million transitions")
    if args.pixels:
        pix, pix_bytes = simdist_rate(DatasetConfig(episodes=4, shard_episodes=4,
                                                    episode_steps=50, pixels=True))
        print(f"simdist dataset generation (64px)  {pix:8.1f} transitions/s  "
              f"{pix_bytes / 1e9:.2f} GB per million transitions")


if __name__ == "__main__":
    main()
