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

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import simdist  # noqa: F401
from simdist.envs import TARGETS, get_target, get_task
from simdist.envs.manipulation import GRIDS
from simdist.experts import Expert, SACExpertConfig, evaluate, resolve_expert, train_sac_expert
from simdist.utils import atomic_path, load_checkpoint, write_json_atomic
from simdist.utils.cli import check, check_builds, check_positive, parse_config


@dataclass
class TrainExpertConfig:
    """The expert's training run; every field is a flag, checked before any work."""

    # output folder (the committed expert lives in checkpoints/quadruped_expert: name it
    # to replace it); rerunning resumes from its latest.pt
    out: str = "outputs/quadruped_expert"
    frames: int = SACExpertConfig.total_frames  # environment frames of SAC
    task: str = "quadruped-terrain"  # the task the expert trains on
    init: str = "narrow"  # manipulation tasks: initial-condition grid (narrow, wide)
    # environment steps per training episode (0: the task's own length)
    episode_steps: int = 0
    init_from: str | None = None  # expert.pt whose actor and critic start the run
    alpha_init: float = SACExpertConfig.alpha_init  # SAC's initial entropy temperature
    # frames before the first update (random actions unless --init-from)
    init_random_frames: int = SACExpertConfig.init_random_frames
    # SAC updates per collected batch of frames
    updates_per_batch: int = SACExpertConfig.updates_per_batch
    # train in this target domain (an online oracle for it), e.g. slippery_slope
    target: str | None = None
    seed: int = 0  # seed of the run (environments, networks, replay)
    progress: bool = True  # a progress bar

    def __post_init__(self):
        check_builds("task", get_task, self.task)
        check_positive(self, "frames", "alpha_init", "updates_per_batch")
        check_positive(self, "init_random_frames", "episode_steps", allow_zero=True)
        check(self.init in GRIDS, "init", f"unknown grid {self.init!r}; valid: {sorted(GRIDS)}")
        if self.target is not None:
            check_builds("target", get_target, self.target)
        if self.init_from is not None:
            check(Path(self.init_from).exists() or resolve_expert(self.init_from).exists(),
                  "init_from", f"no expert checkpoint at {self.init_from}")


def plot_training_curve(curve: list[dict], path) -> None:
    """Evaluation return and the task's reading (forward progress or success) against
    frames (``training_curve.png``)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frames = [point["frames"] for point in curve]
    fig, (left, right) = plt.subplots(1, 2, figsize=(9, 3.2))
    left.plot(frames, [point["return"] for point in curve], marker="o")
    left.set(xlabel="frames", ylabel="evaluation return", title="SAC expert")
    reading = "success" if curve and "success" in curve[0] else "forward_progress"
    right.plot(frames, [point.get(reading, float("nan")) for point in curve], marker="o")
    right.set(xlabel="frames", ylabel="success rate" if reading == "success" else
              "forward progress (m)", title="per evaluation episode")
    for ax in (left, right):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)


def main(argv=None):
    args, _ = parse_config(TrainExpertConfig, {"default": {}}, argv,
                           description=__doc__.splitlines()[0], prog="train_expert.py")
    init_from = args.init_from
    if init_from and not Path(init_from).exists():  # a shipped expert, from any directory
        init_from = str(resolve_expert(init_from))
    cfg = SACExpertConfig(task=args.task, total_frames=args.frames, seed=args.seed,
                          init_from=init_from, alpha_init=args.alpha_init,
                          init_random_frames=args.init_random_frames,
                          updates_per_batch=args.updates_per_batch, target=args.target,
                          init=args.init, episode_steps=args.episode_steps
                          or get_task(args.task).max_episode_steps)
    path = train_sac_expert(cfg, args.out, progress=args.progress)
    expert = Expert.load(path)
    plot_training_curve(load_checkpoint(path)["curve"], path.parent / "training_curve.png")
    if not args.task.startswith("quadruped"):  # the named targets are the quadruped's
        report = {"sim": evaluate(expert.actor, dataclasses.replace(
            cfg, dynamics_randomisation=False, target=None), episodes=16, seed=123)}
        print(f"sim: {report['sim']}")
        write_json_atomic(path.parent / "transfer.json", report)
        return
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
