"""SimDist on the quadruped: pretrain in simulation, plan, finetune dynamics on target data.

Status: only the **environment stage** exists yet (the world model, planner, expert and
dataset stages land with their issues). This stage builds the simulation task and every
requested target domain, drives them with the same open-loop gait, and reports how far
the robot gets in each - a first look at how much each "real world" shifts the physics.

Usage:
    python recipes/simdist_quadruped.py                  # small CPU default
    python recipes/simdist_quadruped.py --preset tiny    # seconds, used by the tests
    python recipes/simdist_quadruped.py --targets slippery_slope foam --episodes 5
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import simdist  # noqa: F401  (headless GL set-up before dm_control)
import numpy as np
import torch
from tqdm import tqdm

from simdist.envs import TARGETS, describe_ranges, make_env
from simdist.utils import StageRunner


@dataclass
class Config:
    """Flat recipe config; presets below override fields."""

    task: str = "quadruped-flat"
    targets: list[str] = field(default_factory=lambda: ["sim", "slippery_slope", "foam",
                                                         "payload", "weak_motors"])
    episodes: int = 3
    episode_steps: int = 250  # 5 s at 50 Hz
    gait_amplitude: float = 0.8
    gait_frequency_hz: float = 2.4
    seed: int = 0
    output_dir: str = "outputs/simdist_quadruped"


PRESETS = {
    "default": {},
    "tiny": {"episodes": 1, "episode_steps": 20, "targets": ["sim", "slippery_slope"]},
    "paper": {"episodes": 15, "episode_steps": 500},
}


def gait(t: int, cfg: Config) -> torch.Tensor:
    """A fixed open-loop joint pattern (a stand-in until the planner stage exists)."""
    phase = 2 * np.pi * cfg.gait_frequency_hz * t * 0.02 + np.arange(12)
    return torch.tensor(cfg.gait_amplitude * np.sin(phase), dtype=torch.float32)


def evaluate(target: str, cfg: Config) -> dict:
    env = make_env(cfg.task, target=target, seed=cfg.seed, max_episode_steps=cfg.episode_steps)
    progress, returns = [], []
    for _ in range(cfg.episodes):
        td = env.reset()
        total = 0.0
        for t in range(cfg.episode_steps):
            td["action"] = gait(t, cfg)
            td = env.step(td)["next"]
            total += td["reward"].item()
        progress.append(td["forward_progress"].item())
        returns.append(total)
    return {"forward_progress_m": progress, "return": returns}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", choices=sorted(PRESETS), default="default")
    parser.add_argument("--targets", nargs="+", help=f"any of {sorted(TARGETS)}")
    parser.add_argument("--episodes", type=int)
    parser.add_argument("--output-dir")
    args = parser.parse_args(argv)
    cfg = dataclasses.replace(Config(), **PRESETS[args.preset])
    overrides = {k: v for k, v in (("targets", args.targets), ("episodes", args.episodes),
                                   ("output_dir", args.output_dir)) if v is not None}
    cfg = dataclasses.replace(cfg, **overrides)
    unknown = [t for t in cfg.targets if t not in TARGETS]
    if unknown:
        parser.error(f"unknown targets {unknown}; valid: {sorted(TARGETS)}")
    out = Path(cfg.output_dir)
    runner = StageRunner(out, cfg)  # finished stages are skipped when rerun

    print("Training randomisation vs target domains:\n" + describe_ranges() + "\n")

    def environment_stage(stage_dir):
        return {target: evaluate(target, cfg)
                for target in tqdm(cfg.targets, desc="environment stage: domains")}

    if runner.done("environment"):
        print("environment stage: already done, reusing its results")
    results = runner.run("environment", environment_stage)
    elapsed = runner.timings["environment"]

    print(f"\n{'domain':16s} {'forward progress (m)':>22s} {'return':>14s}")
    for target, r in results.items():
        p, g = np.array(r["forward_progress_m"]), np.array(r["return"])
        print(f"{target:16s} {p.mean():10.2f} +- {p.std():<8.2f} {g.mean():8.1f} +- {g.std():.1f}")
    print(f"\nenvironment stage: {elapsed:.1f} s "
          f"({len(cfg.targets) * cfg.episodes * cfg.episode_steps / elapsed:.0f} steps/s)")

    (out / "results.json").write_text(json.dumps(
        {"config": dataclasses.asdict(cfg), "stage": "environment", "results": results,
         "seconds": elapsed}, indent=2))
    _plot(results, out / "forward_progress.png")
    print(f"wrote {out / 'results.json'} and {out / 'forward_progress.png'}")


def _plot(results: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(results)
    means = [np.mean(results[n]["forward_progress_m"]) for n in names]
    stds = [np.std(results[n]["forward_progress_m"]) for n in names]
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.bar(names, means, yerr=stds, color="tab:blue", alpha=0.8)
    ax.set_ylabel("forward progress (m)")
    ax.set_title("Open-loop gait in sim and target domains")
    ax.axhline(0, color="k", lw=0.5)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    main()
