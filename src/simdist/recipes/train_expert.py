"""Train the state-based SAC expert used by the SimDist recipe (and resume if interrupted).

Writes to `outputs/quadruped_expert` unless `--out` says otherwise, so a quick run never
overwrites the committed expert; rerunning a command resumes from `latest.pt` there.

The committed experts came from two commands (README, "Experts and perturbed data"):

    # 1. flat ground, from scratch: 400k frames, ~2.2 h on 2 cores
    python recipes/train_expert.py --task quadruped-flat --out checkpoints/quadruped_expert_flat
    # 2. mixed terrain (slopes of -15..15 degrees), continuing the flat expert
    python recipes/train_expert.py --task quadruped-terrain --frames 80000 \
        --init-from checkpoints/quadruped_expert_flat/expert.pt --alpha-init 0.02 \
        --init-random-frames 10000 --updates-per-batch 16 --out checkpoints/quadruped_expert

    python recipes/train_expert.py --frames 20000        # a quick look
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import simdist  # noqa: F401
from simdist.experts import Expert, SACExpertConfig, evaluate, resolve_expert, train_sac_expert
from simdist.envs import TARGETS, get_task
from simdist.utils import atomic_path, load_checkpoint, write_json_atomic


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
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--out", default="outputs/quadruped_expert",
                        help="output directory (the committed expert lives in "
                             "checkpoints/quadruped_expert: name it to replace it)")
    parser.add_argument("--frames", type=int, default=SACExpertConfig.total_frames)
    parser.add_argument("--task", default="quadruped-terrain")
    parser.add_argument("--init-from", default=None,
                        help="expert.pt whose actor and critic start the run")
    parser.add_argument("--alpha-init", type=float, default=SACExpertConfig.alpha_init)
    parser.add_argument("--init-random-frames", type=int,
                        default=SACExpertConfig.init_random_frames,
                        help="frames before the first update (random actions unless "
                             "--init-from)")
    parser.add_argument("--updates-per-batch", type=int,
                        default=SACExpertConfig.updates_per_batch,
                        help=f"SAC updates per {SACExpertConfig.frames_per_batch} frames")
    parser.add_argument("--target", default=None,
                        help="train in this target domain (an online oracle for it, e.g. "
                             "`--task quadruped-flat --target slippery_slope`)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    get_task(args.task)  # an unknown task fails before any work
    init_from = args.init_from
    if init_from and not Path(init_from).exists():  # a shipped expert, from any directory
        init_from = str(resolve_expert(init_from))
    cfg = SACExpertConfig(task=args.task, total_frames=args.frames, seed=args.seed,
                          init_from=init_from, alpha_init=args.alpha_init,
                          init_random_frames=args.init_random_frames,
                          updates_per_batch=args.updates_per_batch, target=args.target)
    path = train_sac_expert(cfg, args.out, progress=not args.no_progress)
    expert = Expert.load(path)
    plot_training_curve(load_checkpoint(path)["curve"], path.parent / "training_curve.png")
    report = {}
    for target in ("sim", "slippery_slope", "foam", "payload", "weak_motors", "laggy"):
        # Transfer is measured on the flat-ground task the targets are defined on.
        flat = dataclasses.replace(cfg, task="quadruped-flat", dynamics_randomisation=False,
                                   target=None)
        report[target] = evaluate(expert.actor, flat, episodes=6, seed=123,
                                  target=None if target == "sim" else TARGETS[target])
        print(f"{target:15s} return {report[target]['return']:7.1f}   "
              f"forward progress {report[target]['forward_progress']:5.2f} m")
    write_json_atomic(path.parent / "transfer.json", report)


def cli() -> None:
    """The ``simdist-train-expert`` console script: :func:`main` on ``sys.argv``, exit status 0."""
    main()


if __name__ == "__main__":
    main()
