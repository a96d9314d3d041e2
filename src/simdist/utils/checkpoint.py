"""Atomic checkpoints that load without running pickled code, and say what to do if corrupt."""

from __future__ import annotations

import os
import re
from pathlib import Path

import torch

from simdist.utils.atomic import atomic_path


class CorruptFileError(RuntimeError):
    """A file the library reads is truncated, garbled or of an incompatible format.

    The message names the file, says what is wrong with it and how to recover (which file
    and stage record to delete so that a rerun recreates them).

    Examples:
        >>> import json, tempfile
        >>> from simdist.utils.stages import read_json
        >>> path = Path(tempfile.mkdtemp()) / "stages" / "teacher.json"
        >>> path.parent.mkdir(); _ = path.write_text('{"result": ')
        >>> try:
        ...     read_json(path, "stage record")
        ... except CorruptFileError as err:
        ...     print("teacher.json" in str(err), "delete" in str(err))
        True True
    """


class CorruptCheckpointError(CorruptFileError):
    """A checkpoint that a weights-only ``torch.load`` cannot read (see :func:`load_checkpoint`).

    Examples:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "model.pt"
        >>> _ = path.write_bytes(b"not a checkpoint")
        >>> try:
        ...     load_checkpoint(path)
        ... except CorruptCheckpointError as err:
        ...     print(str(path) in str(err), "weights_only=False" in str(err))
        True False
    """


def recovery_hint(path: str | os.PathLike) -> str:
    """How to get rid of a bad file so that a rerun recreates it.

    Files under ``<out>/stages/<stage>/`` (and the record ``<out>/stages/<stage>.json``)
    belong to a recipe stage: deleting the file and the stage's record makes the next run
    of the same command redo that stage. Anything else is to be recreated by its writer.

    Examples:
        >>> hint = recovery_hint("out/stages/pretrain/world_model.pt")
        >>> hint.startswith("delete out/stages/pretrain/world_model.pt and the stage record "
        ...                 "out/stages/pretrain.json"), hint.endswith("'pretrain' runs again")
        (True, True)
    """
    path = Path(path)
    parts = path.parts
    if "stages" in parts[:-1]:
        i = len(parts) - 1 - parts[::-1].index("stages")  # the innermost "stages" folder
        stages = Path(*parts[:i + 1])
        if i == len(parts) - 2 and path.suffix == ".json":  # the stage record itself
            return (f"delete {path}, then rerun the same command: stage {path.stem!r} "
                    "runs again")
        stage = parts[i + 1]
        record = stages / f"{stage}.json"
        return (f"delete {path} and the stage record {record} (if present), then rerun "
                f"the same command: stage {stage!r} runs again")
    return (f"delete or replace {path} (recreate it with the command that wrote it), or "
            "pass the path of a good copy")


def save_atomic(obj, path: str | os.PathLike) -> None:
    """Writes ``obj`` with ``torch.save`` to a temp file, then renames it into place.

    A crash mid-write leaves the previous checkpoint intact: ``os.replace`` is atomic on
    POSIX file systems.
    """
    with atomic_path(path) as tmp:
        torch.save(obj, tmp)


def load_checkpoint(path: str | os.PathLike, map_location="cpu", recovery: str | None = None):
    """Loads a checkpoint with ``weights_only=True`` (tensors, dicts, numbers, strings).

    Args:
        path: the ``.pt`` file.
        map_location: as for ``torch.load``.
        recovery: what to tell the user to do if the file is corrupt (default:
            :func:`recovery_hint`).

    Raises:
        FileNotFoundError: naming the missing file and how to create it.
        CorruptCheckpointError: the file is truncated, garbled, not a torch checkpoint, or
            holds pickled objects (which are never unpickled: they could run code).
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"checkpoint {str(path)!r} does not exist; train it first "
                                "(see the recipe's --help) or pass the right path")
    try:
        return torch.load(path, map_location=map_location, weights_only=True)
    except OSError as err:
        if err.filename is not None:  # e.g. a folder or an unreadable file: already named
            raise
        error = err
    except Exception as err:  # torch reports corruption as any of a dozen types
        if "deserialize object on" in str(err):  # a device problem, not a corrupt file
            raise
        error = err
    # ``from None``: the chained torch error would repeat its advice to load with
    # weights_only=False, which runs whatever code the file holds.
    raise CorruptCheckpointError(_message(path, error, recovery)) from None


def _message(path: Path, err: Exception, recovery: str | None) -> str:
    text = str(err)
    if "Weights only load failed" in text:
        # Never repeat torch's advice to retry with weights_only=False: that runs the
        # file's pickled code. Keep only the name of the refused object.
        refused = re.search(r"\bGLOBAL ([A-Za-z_][\w.]*)", text)
        if refused:
            reason = (f"it holds pickled Python objects ({refused.group(1)}) besides tensors "
                      "and plain containers; those are never unpickled, because unpickling "
                      "can run arbitrary code")
        else:
            reason = ("it is garbled or holds data other than tensors and plain containers "
                      "(refused: unpickling arbitrary data can run code)")
    else:
        # torch's own first sentence, unless it is advice about weights_only.
        first = text.strip().split(". ")[0].splitlines()[0][:160] if text.strip() else ""
        first = "" if "weights_only" in first else first
        reason = (f"it is truncated, garbled or not a torch checkpoint "
                  f"({type(err).__name__}{': ' + first if first else ''})")
    return (f"checkpoint {str(path)!r} is corrupt or incompatible: {reason}. To recover, "
            f"{recovery or recovery_hint(path)}")
