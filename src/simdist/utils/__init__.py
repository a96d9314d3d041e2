"""Utilities: atomic checkpoints, checkpointed recipe stages."""

from simdist.utils.checkpoint import load_checkpoint, save_atomic
from simdist.utils.stages import StageRunner, run_jobs

__all__ = ["load_checkpoint", "save_atomic", "StageRunner", "run_jobs"]
