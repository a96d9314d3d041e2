"""Utilities: atomic checkpoints, checkpointed recipe stages, devices."""

from simdist.utils.checkpoint import load_checkpoint, save_atomic
from simdist.utils.device import (device_argument, module_device, move_to_device,
                                  resolve_device)
from simdist.utils.stages import StageRunner, run_jobs

__all__ = ["load_checkpoint", "save_atomic", "StageRunner", "run_jobs", "device_argument",
           "module_device", "move_to_device", "resolve_device"]
