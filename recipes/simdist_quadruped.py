"""SimDist on the quadruped: pretrain in simulation, plan, finetune dynamics on target data.

Status: the expert stages run (load or retrain the state-based SAC expert; measure its
zero-shot transfer to every target domain). Dataset, world-model pretraining, latent MPPI
deployment and dynamics-only finetuning rounds are wired in by the SimDist pipeline issue;
their parts already exist (`simdist.data`, `simdist.agents.SimDistAgent`,
`simdist.pipelines`). Stages are checkpointed: rerunning skips finished ones.

Usage:
    python recipes/simdist_quadruped.py                  # small CPU default
    python recipes/simdist_quadruped.py --preset tiny    # seconds, used by the tests
    python recipes/simdist_quadruped.py --targets slippery_slope foam --episodes 9
    python recipes/simdist_quadruped.py --retrain-expert # hours on 2 CPU cores
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import simdist  # noqa: F401  (headless GL set-up before dm_control)
import numpy as np
from tqdm import tqdm

from simdist.envs import TARGETS, describe_ranges, get_target
from simdist.experts import Expert, SACExpertConfig, train_sac_expert
from simdist.pipelines import locomotion_env, progress_stats, rollout
from simdist.utils import StageRunner

DEFAULT_EXPERT = "checkpoints/quadruped_expert/expert.pt"


@dataclass
class Config:
    """Flat recipe config; presets below override fields. Saved as ``config.json``."""

    task: str = "quadruped-flat"
    expert: str = DEFAULT_EXPERT
    retrain_expert: bool = False
    expert_frames: int = SACExpertConfig.total_frames
    targets: list[str] = field(default_factory=lambda: ["sim", "slippery_slope", "foam",
                                                         "payload", "weak_motors"])
    episodes: int = 6
    episode_steps: int = 250  # 5 s at 50 Hz
    seed: int = 0
    output_dir: str = "outputs/simdist_quadruped"


PRESETS = {
    "default": {},
    "tiny": {"episodes": 2, "episode_steps": 20, "targets": ["sim", "slippery_slope"]},
    "paper": {"episodes": 15, "episode_steps": 500},
}


def expert_stage(cfg: Config, stage_dir: Path) -> dict:
    """Loads the committed expert, or retrains it (resumable) when asked."""
    path = Path(cfg.expert)
    if cfg.retrain_expert:
        path = train_sac_expert(SACExpertConfig(task=cfg.task, total_frames=cfg.expert_frames,
                                                seed=cfg.seed), stage_dir)
    if not path.exists():
        raise FileNotFoundError(
            f"no expert checkpoint at {path}: train one with `python recipes/train_expert.py` "
            "or rerun this recipe with --retrain-expert")
    expert = Expert.load(path)  # fails clearly on a corrupt or incompatible file
    del expert
    return {"path": str(path)}


def zero_shot_stage(cfg: Config, expert_path: str) -> dict:
    """The expert's forward progress in simulation and in each target domain."""
    policy = Expert.load(expert_path).deterministic()
    results = {}
    for target in tqdm(cfg.targets, desc="expert zero-shot: domains"):
        env = locomotion_env(get_target(target), cfg.episodes, cfg.episode_steps, cfg.seed)
        command = env.base_env.observation_layout["command"].start
        results[target] = progress_stats(rollout(env, policy, cfg.episode_steps), command)
        env.close()
    return results


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", choices=sorted(PRESETS), default="default")
    parser.add_argument("--targets", nargs="+", help=f"any of {sorted(TARGETS)}")
    parser.add_argument("--episodes", type=int)
    parser.add_argument("--expert", help=f"expert checkpoint (default {DEFAULT_EXPERT})")
    parser.add_argument("--retrain-expert", action="store_true")
    parser.add_argument("--output-dir")
    args = parser.parse_args(argv)
    cfg = dataclasses.replace(Config(), **PRESETS[args.preset])
    overrides = {k: v for k, v in (("targets", args.targets), ("episodes", args.episodes),
                                   ("expert", args.expert), ("output_dir", args.output_dir))
                 if v is not None}
    cfg = dataclasses.replace(cfg, retrain_expert=args.retrain_expert, **overrides)
    unknown = [t for t in cfg.targets if t not in TARGETS]
    if unknown:
        parser.error(f"unknown targets {unknown}; valid: {sorted(TARGETS)}")
    out = Path(cfg.output_dir)
    runner = StageRunner(out, cfg)  # finished stages are skipped when rerun
    print("Training randomisation vs target domains:\n" + describe_ranges() + "\n")

    for name in ("expert", "expert_zero_shot"):
        if runner.done(name):
            print(f"stage {name}: already done, reusing its results")
    expert = runner.run("expert", lambda d: expert_stage(cfg, d))
    results = runner.run("expert_zero_shot", lambda d: zero_shot_stage(cfg, expert["path"]))

    print(f"\nExpert zero-shot, {cfg.episodes} episodes x {cfg.episode_steps} steps per domain")
    print(f"{'domain':16s} {'forward progress (m)':>22s} {'of commanded distance':>24s}")
    for target, r in results.items():
        print(f"{target:16s} {r['mean_m']:10.2f} +- {r['std_m']:<8.2f} "
              f"{100 * r['mean_fraction']:14.0f}% +- {100 * r['std_fraction']:.0f}%")
    print("\nstage timings: " + ", ".join(f"{k} {v:.1f} s" for k, v in runner.timings.items()))
    (out / "results.json").write_text(json.dumps(
        {"config": dataclasses.asdict(cfg), "expert": expert, "expert_zero_shot": results,
         "timings_s": runner.timings}, indent=2))
    _plot(results, out / "forward_progress.png")
    print(f"wrote {out / 'results.json'} and {out / 'forward_progress.png'}")


def _plot(results: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(results)
    means = [100 * results[n]["mean_fraction"] for n in names]
    stds = [100 * results[n]["std_fraction"] for n in names]
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.bar(names, means, yerr=stds, color="tab:blue", alpha=0.8)
    ax.set_ylabel("forward progress\n(% of commanded)")
    ax.set_title("State-based expert, zero-shot in each domain")
    ax.axhline(0, color="k", lw=0.5)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    main()
