"""Atomic checkpoints that load without running pickled code."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import torch


def save_atomic(obj, path: str | os.PathLike) -> None:
    """Writes ``obj`` with ``torch.save`` to a temp file, then renames it into place.

    A crash mid-write leaves the previous checkpoint intact: ``os.replace`` is atomic on
    POSIX file systems.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    os.close(fd)
    try:
        torch.save(obj, tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def load_checkpoint(path: str | os.PathLike, map_location="cpu"):
    """Loads a checkpoint with ``weights_only=True`` (tensors, dicts, numbers, strings).

    Raises:
        FileNotFoundError: naming the missing file and how to create it.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"checkpoint {str(path)!r} does not exist; train it first "
                                "(see the recipe's --help) or pass the right path")
    return torch.load(path, map_location=map_location, weights_only=True)
