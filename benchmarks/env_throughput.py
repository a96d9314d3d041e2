"""Environment throughput: simdist envs vs a raw dm_control loop, measured in the same run.

Reports env steps/s for state-only quadruped and for 64x64 pixels, each as a ratio to the
raw dm_control loop (``suite.load(...).step`` on the same task family, zero actions),
plus TorchRL's stock ``DMControlEnv`` for reference. This machine's throughput drifts by
up to 2x between seconds, so each repeat runs every contender back to back, ratios are
taken within a repeat (paired), and medians over many short repeats are reported.

Usage:
    python benchmarks/env_throughput.py            # ~2 minutes on 2 cores
    python benchmarks/env_throughput.py --quick    # ~20 s smoke run
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import simdist  # noqa: F401  (headless GL set-up before dm_control)
import numpy as np
import torch
from dm_control import suite
from torchrl.envs import DMControlEnv

from simdist.envs import make_env


def _raw_loop(domain, task, steps, pixels, camera_id):
    env = suite.load(domain, task, task_kwargs={"random": 0})
    env.reset()
    action = np.zeros(env.action_spec().shape)

    def run():
        start = time.perf_counter()
        for _ in range(steps):
            ts = env.step(action)
            if pixels:
                env.physics.render(64, 64, camera_id=camera_id)
            if ts.last():
                env.reset()
        return steps / (time.perf_counter() - start)
    return run


def _torchrl_loop(env, steps):
    td = env.reset()
    zeros = torch.zeros(env.action_spec.shape)

    def run():
        nonlocal td
        start = time.perf_counter()
        for _ in range(steps):
            td["action"] = zeros
            _, td = env.step_and_maybe_reset(td)
        return steps * max(1, env.batch_size.numel()) / (time.perf_counter() - start)
    return run


def measure(contenders: dict, repeats: int, reference_for) -> dict:
    """Median rate and median paired ratio to the reference, per contender."""
    rates = {name: [] for name in contenders}
    for run in contenders.values():
        run()  # warm-up
    for _ in range(repeats):
        for name, run in contenders.items():
            rates[name].append(run())
    return {name: {"steps_per_s": statistics.median(r),
                   "ratio_to_raw": statistics.median(
                       a / b for a, b in zip(r, rates[reference_for(name)])),
                   "spread": [min(r), max(r)]}
            for name, r in rates.items()}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--json", help="write the figures to this file")
    args = parser.parse_args()
    torch.set_num_threads(1)
    steps, pixel_steps, repeats = (300, 10, 2) if args.quick else (500, 30, 11)

    def state_ref(name):
        return "raw dm_control quadruped-walk"

    def pixel_ref(name):
        return ("raw dm_control cartpole-balance + 64px render" if "cartpole" in name
                else "raw dm_control quadruped-walk + 64px render")

    state = measure({
        "raw dm_control quadruped-walk": _raw_loop("quadruped", "walk", steps, False, 2),
        "simdist quadruped-flat (1 env)": _torchrl_loop(make_env("quadruped-flat"), steps),
        "simdist quadruped-flat (16 envs)": _torchrl_loop(
            make_env("quadruped-flat", num_envs=16), max(1, steps // 16)),
        "torchrl DMControlEnv quadruped-walk": _torchrl_loop(
            DMControlEnv("quadruped", "walk"), steps),
    }, repeats, state_ref)
    pixels = measure({
        "raw dm_control quadruped-walk + 64px render": _raw_loop("quadruped", "walk",
                                                                 pixel_steps, True, 2),
        "simdist quadruped-flat pixels": _torchrl_loop(
            make_env("quadruped-flat", pixels=True), pixel_steps),
        "raw dm_control cartpole-balance + 64px render": _raw_loop("cartpole", "balance",
                                                                   pixel_steps, True, 0),
        "simdist cartpole-balance pixels": _torchrl_loop(
            make_env("cartpole-balance", pixels=True), pixel_steps),
        "simdist cartpole-balance pixels + per-step visual DR": _torchrl_loop(
            make_env("cartpole-balance", pixels=True,
                     visual_randomisation=simdist.envs.VisualRandomisation.training()),
            pixel_steps),
    }, max(2, repeats // 3), pixel_ref)

    def table(results):
        print(f"{'contender':56s} {'steps/s':>8s} {'x raw':>6s}  {'min-max steps/s':>16s}")
        for name, r in results.items():
            lo, hi = r["spread"]
            print(f"{name:56s} {r['steps_per_s']:8.0f} {r['ratio_to_raw']:6.2f}  "
                  f"{lo:7.0f}-{hi:<8.0f}")

    print(f"\nState-only (one core, zero actions, {repeats} paired repeats)")
    table(state)
    print("\nPixels, 64x64, software EGL")
    table(pixels)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"state": state, "pixels": pixels}, f, indent=2)


if __name__ == "__main__":
    main()
