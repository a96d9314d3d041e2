"""Dataset generation throughput vs a raw dm_control loop, in the same run.

"simdist" = one shard of perturbed-expert episodes exactly as ``generate_dataset`` makes
them: batched quadruped env, episode mixture of two 256-wide SAC actors, perturbation
schedule, critic value labels, and the write into a memory-mapped dataset. "raw" = a
``dm_control.suite`` quadruped loop with zero actions and no policy, no storage (with
``--pixels`` also rendering 64x64 from the same camera every step). The two alternate
``--repeats`` times in one process; medians are reported. Both use one torch thread and
one process, so the ratio is per core.

Usage:
    python benchmarks/dataset_generation.py           # ~3 minutes
    python benchmarks/dataset_generation.py --pixels  # adds 64x64 pixel rows (~3 more)
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time

import numpy as np
import torch

import simdist  # noqa: F401  (first: it picks MUJOCO_GL before dm_control reads it)
from dm_control import suite  # noqa: E402
from simdist.data import DatasetConfig, generate_dataset
from simdist.experts import Expert


def raw_rate(steps: int, pixels: bool = False) -> float:
    env = suite.load("quadruped", "walk", task_kwargs={"random": 0})
    env.reset()
    action = np.zeros(env.action_spec().shape)
    start = time.perf_counter()
    for _ in range(steps):
        last = env.step(action).last()
        if pixels:  # camera 2 follows the body: the quadruped tasks' render camera
            env.physics.render(64, 64, camera_id=2)
        if last:
            env.reset()
    return steps / (time.perf_counter() - start)


def simdist_rate(cfg: DatasetConfig) -> tuple[float, float]:
    torch.manual_seed(0)
    experts = (Expert.untrained(89, 12), [Expert.untrained(89, 12)])
    with tempfile.TemporaryDirectory() as out:
        start = time.perf_counter()
        path = generate_dataset(cfg, out, *experts, progress=False)
        elapsed = time.perf_counter() - start
        meta = json.loads((path / "meta.json").read_text())
    return meta["transitions"] / elapsed, meta["bytes"] / meta["transitions"] * 1e6


def paired(raw, ours, repeats: int) -> tuple[float, float, float]:
    """Medians of ``repeats`` alternating (raw, ours, raw) measurements."""
    raws, rates, sizes = [], [], []
    for _ in range(repeats):
        raws.append(raw())
        rate, size = ours()
        rates.append(rate)
        sizes.append(size)
    raws.append(raw())
    return float(np.median(raws)), float(np.median(rates)), float(np.median(sizes))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pixels", action="store_true")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--shard-episodes", type=int, default=32,
                        help="worlds stepped together in one process (state-only rows)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    state_cfg = DatasetConfig(episodes=3 * args.shard_episodes,
                              shard_episodes=args.shard_episodes, episode_steps=250)
    raw, ours, bytes_per_m = paired(lambda: raw_rate(3000), lambda: simdist_rate(state_cfg),
                                    args.repeats)
    print(f"raw dm_control quadruped loop             {raw:8.0f} steps/s")
    print(f"simdist dataset generation (state, {args.shard_episodes} worlds per shard)")
    print(f"                                          {ours:8.0f} transitions/s  "
          f"{ours / raw:.2f}x raw   {bytes_per_m / 1e9:.2f} GB per million transitions")
    if args.pixels:
        pixel_cfg = DatasetConfig(episodes=8, shard_episodes=4, episode_steps=100, pixels=True)
        raw, ours, bytes_per_m = paired(lambda: raw_rate(400, pixels=True),
                                        lambda: simdist_rate(pixel_cfg), args.repeats)
        print(f"raw dm_control quadruped loop + 64px      {raw:8.1f} steps/s")
        print(f"simdist dataset generation (state + 64px) {ours:8.1f} transitions/s  "
              f"{ours / raw:.2f}x raw   {bytes_per_m / 1e9:.2f} GB per million transitions")


if __name__ == "__main__":
    main()
