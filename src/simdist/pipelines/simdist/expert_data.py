"""The expert stage and the perturbed-expert dataset stage (SimDist steps 1-2)."""

from __future__ import annotations

from pathlib import Path

import simdist  # noqa: F401  (headless GL set-up before dm_control)
from simdist.data import generate_dataset
from simdist.data.dataset import read_dataset_meta
from simdist.experts import Expert, SACExpertConfig, resolve_expert, train_sac_expert
from simdist.pipelines.simdist.config import Config, dataset_config
from simdist.pipelines.simdist.jobs import stage_jobs
from simdist.utils import load_checkpoint, load_memmap


def expert_stage(cfg: Config, stage_dir: Path) -> dict:
    """Loads the committed expert, or retrains it (resumable) when asked."""
    path = resolve_expert(cfg.expert)  # the default is shipped as package data
    if cfg.retrain_expert:
        path = train_sac_expert(SACExpertConfig(task=cfg.data_task, total_frames=cfg.expert_frames,
                                                seed=cfg.seed), stage_dir)
    if not path.exists():
        raise FileNotFoundError(
            f"no expert checkpoint at {path}: train one with `python recipes/train_expert.py` "
            "or rerun this recipe with --retrain-expert")
    Expert.load(path)  # fails clearly on a corrupt or incompatible file
    return {"path": str(path)}


def load_experts(expert_path: str) -> tuple[Expert, list[Expert]]:
    """The final expert and its earlier snapshots (the dataset's policy mixture)."""
    snapshots = sorted(load_checkpoint(expert_path)["snapshots"])
    return Expert.load(expert_path), [Expert.load(expert_path, snapshot=s) for s in snapshots]


def dataset_stage(cfg: Config, expert_path: str, stage_dir: Path) -> dict:
    jobs, threads = stage_jobs(cfg, dataset_config(cfg).shards)
    path = generate_dataset(dataset_config(cfg), stage_dir / "data", *load_experts(expert_path),
                            jobs=jobs, threads=threads)
    meta = read_dataset_meta(path)
    data = load_memmap(path / "data", manifest=meta["files"])
    return {"path": str(path), "transitions": meta["transitions"], "bytes": meta["bytes"],
            "generation_s": meta["seconds"],
            "noised_fraction": data["noised"].float().mean().item(),
            "final_expert_unnoised_fraction": data["expert_active"].float().mean().item()}
