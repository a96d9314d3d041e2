"""Generate a perturbed-expert dataset on disk (resumable: rerun the same command).

Usage:
    python recipes/generate_dataset.py --expert checkpoints/quadruped_expert/expert.pt \
        --episodes 64 --steps 250 --out outputs/datasets/quadruped
    # the same shards as Ray tasks (a local cluster, or the one RAY_ADDRESS names):
    python recipes/generate_dataset.py --backend ray --episodes 4000 --shard-episodes 32
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import simdist  # noqa: F401
from simdist.data import DatasetConfig, generate_dataset
from simdist.experts import Expert, resolve_expert
from simdist.utils import load_checkpoint
from simdist.utils.cli import check, check_positive, exit_on_folder_errors, parse_config


@dataclass
class GenerateDatasetConfig:
    """The dataset to generate; every field is a flag, checked before any work."""

    expert: str = "checkpoints/quadruped_expert/expert.pt"  # the expert checkpoint
    out: str = "outputs/datasets/quadruped"  # output folder (rerun to resume)
    episodes: int = DatasetConfig.episodes  # perturbed-expert episodes
    steps: int = DatasetConfig.episode_steps  # steps per episode
    # worlds stepped together (one collector batch); more amortise the policy's cost
    shard_episodes: int = DatasetConfig.shard_episodes
    workers: int = 1  # processes stepping the worlds (TorchRL ParallelEnv)
    # local, or ray: each shard a Ray task (pip install 'simdist-rl[distributed]')
    backend: str = "local"
    pixels: bool = False  # also record rendered images
    seed: int = 0  # seed of the dataset (shard seeds derive from it)

    def __post_init__(self):
        check_positive(self, "episodes", "steps", "shard_episodes", "workers")
        check(self.backend in ("local", "ray"), "backend",
              f"must be 'local' or 'ray', got {self.backend!r}")
        check(resolve_expert(self.expert).exists(), "expert",
              f"no expert checkpoint at {self.expert}: train one with "
              "`python recipes/train_expert.py`")


def main(argv=None):
    args, _ = parse_config(GenerateDatasetConfig, {"default": {}}, argv,
                           description=__doc__.splitlines()[0], prog="generate_dataset.py")
    expert_path = resolve_expert(args.expert)  # the default is shipped as package data
    snapshots = sorted(load_checkpoint(expert_path)["snapshots"])
    expert = Expert.load(expert_path)
    earlier = [Expert.load(expert_path, snapshot=name) for name in snapshots]
    cfg = DatasetConfig(episodes=args.episodes, episode_steps=args.steps,
                        shard_episodes=args.shard_episodes, num_workers=args.workers,
                        pixels=args.pixels, seed=args.seed)
    with exit_on_folder_errors("generate_dataset.py"):  # another config's dataset in --out
        path = generate_dataset(cfg, args.out, expert, earlier, backend=args.backend)
    meta = json.loads((path / "meta.json").read_text())
    print(f"{meta['transitions']} transitions, {meta['bytes'] / 1e6:.1f} MB, "
          f"{meta['seconds']:.0f} s of generation -> {path}")


def cli() -> None:
    """The ``simdist-dataset`` console script: :func:`main` on ``sys.argv``, exit status 0."""
    main()


if __name__ == "__main__":
    main()
