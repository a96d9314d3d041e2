"""How the pipeline's independent calls share the cores: processes and threads per stage, and a
worker's training history handed back to the logger.
"""

from __future__ import annotations

from pathlib import Path

import torch

import simdist  # noqa: F401  (headless GL set-up before dm_control)
from simdist.pipelines.experiment_log import log_metrics
from simdist.pipelines.simdist.config import Config
from simdist.utils import load_checkpoint


def updates_done(checkpoint: Path) -> int:
    """How many updates a :func:`train_resumable` checkpoint holds (0: none yet)."""
    return len(load_checkpoint(checkpoint)["history"]) if checkpoint.exists() else 0


def log_trained(logger, prefix: str, history: list[dict], done: int) -> None:
    """Logs a worker's updates after the ``done`` its checkpoint already held (workers get
    no logger; a resumed stage logs no update twice)."""
    for step, metrics in enumerate(history[done:], done + 1):
        log_metrics(logger, prefix, metrics, step)


def member_jobs(cfg: Config, members: int | None = None) -> tuple[int, int]:
    """(processes, torch threads each) for training ``members`` models side by side
    (default: the members pretrained independently; one with a shared encoder)."""
    if members is None:
        members = cfg.ensemble_size if not cfg.ensemble_shared_encoder else 1
    threads = cfg.threads or torch.get_num_threads()
    jobs = max(1, min(members, cfg.ensemble_jobs or threads))
    return jobs, max(1, threads // jobs)


def stage_jobs(cfg: Config, calls: int) -> tuple[int, int]:
    """(processes, torch threads each) for ``calls`` independent planner-stage calls
    (``cfg.jobs``; see its comment)."""
    threads = cfg.threads or torch.get_num_threads()
    jobs = max(1, min(calls, cfg.jobs or threads))
    return jobs, max(1, threads // jobs)
