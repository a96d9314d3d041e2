"""Utilities: atomic checkpoints."""

from simdist.utils.checkpoint import load_checkpoint, save_atomic

__all__ = ["load_checkpoint", "save_atomic"]
