"""Train the state-based SAC expert used by the SimDist recipe (and resume if interrupted).

The committed checkpoint `checkpoints/quadruped_expert/expert.pt` came from the default
command below; rerunning it resumes from `latest.pt` in the output directory.

Usage:
    python recipes/train_expert.py                                  # 400k frames, ~hours on 2 cores
    python recipes/train_expert.py --frames 20000 --out /tmp/expert # a quick look
"""

from __future__ import annotations

import argparse
import dataclasses
import json

import simdist  # noqa: F401
from simdist.experts import Expert, SACExpertConfig, evaluate, train_sac_expert
from simdist.envs import TARGETS
from simdist.utils import load_checkpoint


def plot_training_curve(curve: list[dict], path) -> None:
    """Evaluation return and forward progress against frames (``training_curve.png``)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frames = [point["frames"] for point in curve]
    fig, (left, right) = plt.subplots(1, 2, figsize=(9, 3.2))
    left.plot(frames, [point["return"] for point in curve], marker="o")
    left.set(xlabel="frames", ylabel="evaluation return", title="SAC expert")
    right.plot(frames, [point["forward_progress"] for point in curve], marker="o")
    right.set(xlabel="frames", ylabel="forward progress (m)", title="per evaluation episode")
    for ax in (left, right):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="checkpoints/quadruped_expert")
    parser.add_argument("--frames", type=int, default=SACExpertConfig.total_frames)
    parser.add_argument("--task", default=SACExpertConfig.task)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    cfg = SACExpertConfig(task=args.task, total_frames=args.frames, seed=args.seed)
    path = train_sac_expert(cfg, args.out, progress=not args.no_progress)
    expert = Expert.load(path)
    plot_training_curve(load_checkpoint(path)["curve"], path.parent / "training_curve.png")
    report = {}
    for target in ("sim", "slippery_slope", "foam", "payload", "weak_motors", "laggy"):
        report[target] = evaluate(expert.actor, dataclasses.replace(cfg, dynamics_randomisation=False),
                                  episodes=6, seed=123, target=None if target == "sim" else TARGETS[target])
        print(f"{target:15s} return {report[target]['return']:7.1f}   "
              f"forward progress {report[target]['forward_progress']:5.2f} m")
    (path.parent / "transfer.json").write_text(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
