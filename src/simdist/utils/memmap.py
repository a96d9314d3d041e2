"""Memory-mapped TensorDict folders read as data only: no pickles, sizes and checksums checked.

Every folder the library reads (datasets, an online run's episodes, a recipe's round data)
goes through :func:`load_memmap`, which

- refuses pickled non-tensor fields (``allow_pickle=False``): a shared data folder can
  never run code;
- checks every leaf file holds exactly the bytes its ``meta.json`` shape and dtype say,
  *before* tensordict maps it (a short file would otherwise be zero-extended on disk,
  even when opened read-only);
- when a manifest was recorded at write time (:func:`save_memmap`,
  :func:`folder_manifest`), checks each file's size and CRC-32 too.

Failures name the file and say how to recover.
"""

from __future__ import annotations

import json
import os
import shutil
import zlib
from pathlib import Path

import torch
from tensordict import TensorDict
from tensordict.utils import is_non_tensor

MANIFEST = "simdist_manifest.json"
_CHUNK = 1 << 23


class CorruptDataError(RuntimeError):
    """A data file on disk is missing, truncated, altered or unsafe to load.

    Examples:
        >>> import tempfile
        >>> try:
        ...     load_memmap(tempfile.mkdtemp())
        ... except CorruptDataError as err:
        ...     print("no meta.json" in str(err))
        True
    """


def _crc32(path: Path) -> int:
    crc = 0
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            crc = zlib.crc32(chunk, crc)
    return crc


def folder_manifest(folder: str | Path) -> dict:
    """``{relative path: {"bytes": n, "crc32": c}}`` for every file under ``folder``.

    Examples:
        >>> import tempfile
        >>> folder = Path(tempfile.mkdtemp()); (folder / "x.bin").write_bytes(b"abc")
        3
        >>> folder_manifest(folder)
        {'x.bin': {'bytes': 3, 'crc32': 891568578}}
    """
    folder = Path(folder)
    return {str(p.relative_to(folder)): {"bytes": p.stat().st_size, "crc32": _crc32(p)}
            for p in sorted(folder.rglob("*")) if p.is_file() and p.name != MANIFEST}


def _check_manifest(folder: Path, manifest: dict) -> None:
    for name, expected in manifest.items():
        path = folder / name
        if not path.is_file():
            raise CorruptDataError(f"{path} is missing (listed when {folder} was written)")
        size = path.stat().st_size
        if size != expected["bytes"]:
            raise CorruptDataError(f"{path} has {size} bytes, {expected['bytes']} were written: "
                                   "the file is truncated or altered")
        if _crc32(path) != expected["crc32"]:
            raise CorruptDataError(f"{path} fails its checksum: the file was altered or "
                                   "damaged after it was written")


def _check_leaf_sizes(folder: Path) -> None:
    """Each ``*.memmap`` leaf holds numel x itemsize bytes, as its ``meta.json`` says."""
    meta_path = folder / "meta.json"
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, ValueError) as err:
        raise CorruptDataError(f"{meta_path} is unreadable or not JSON ({err})") from err
    for key, entry in meta.items():
        if not isinstance(entry, dict):
            continue
        if entry.get("type") is not None:  # a nested TensorDict: its own folder
            sub = folder / key
            if (sub / "meta.json").exists():
                _check_leaf_sizes(sub)
            continue
        if "shape" not in entry or "dtype" not in entry or entry.get("is_nested"):
            continue
        dtype = getattr(torch, str(entry["dtype"]).removeprefix("torch."), None)
        if not isinstance(dtype, torch.dtype):
            raise CorruptDataError(f"{meta_path}: unknown dtype {entry['dtype']!r} for {key!r}")
        expected = int(torch.Size(entry["shape"]).numel()) * dtype.itemsize
        path = folder / f"{key}.memmap"
        if not path.is_file():
            raise CorruptDataError(f"{path} is missing (listed in {meta_path})")
        size = path.stat().st_size
        if size != expected:
            raise CorruptDataError(f"{path} has {size} bytes but its shape {entry['shape']} and "
                                   f"dtype need {expected}: the file is truncated or altered")


def load_memmap(folder: str | Path, manifest: dict | None = None) -> TensorDict:
    """Loads a memory-mapped TensorDict folder as data only (see the module docstring).

    Args:
        folder: the folder ``TensorDict.memmap`` wrote.
        manifest: sizes and checksums recorded at write time; by default the folder's own
            ``simdist_manifest.json`` when :func:`save_memmap` wrote one.

    Raises:
        CorruptDataError: naming the file that is missing, short, altered, or pickled.

    Examples:
        >>> import tempfile
        >>> folder = Path(tempfile.mkdtemp()) / "episode"
        >>> save_memmap(TensorDict({"x": torch.arange(3.0)}, [3]), folder)
        >>> load_memmap(folder)["x"].tolist()
        [0.0, 1.0, 2.0]
    """
    folder = Path(folder)
    if not (folder / "meta.json").is_file():
        raise CorruptDataError(f"{folder} holds no meta.json: not a memory-mapped TensorDict "
                               "folder, or it was never completely written")
    if manifest is None and (folder / MANIFEST).is_file():
        try:
            manifest = json.loads((folder / MANIFEST).read_text())
        except ValueError as err:
            raise CorruptDataError(f"{folder / MANIFEST} is not JSON ({err})") from err
    _check_leaf_sizes(folder)
    if manifest is not None:
        _check_manifest(folder, manifest)
    try:
        return TensorDict.load_memmap(folder, allow_pickle=False)
    except RuntimeError as err:
        if "pickle" in str(err).lower():
            raise CorruptDataError(
                f"{folder} contains a pickled field, which could run code when loaded; "
                "simdist never writes pickles, so this folder was altered or does not come "
                "from simdist: it was not loaded") from err
        raise


def save_memmap(td: TensorDict, folder: str | Path) -> None:
    """Memory-maps ``td`` into ``folder`` with a manifest, atomically (temp folder, rename).

    A crash leaves either no ``folder`` or a complete one. Non-tensor fields are refused:
    they would be pickled, and :func:`load_memmap` does not read pickles.
    """
    folder = Path(folder)
    bad = [k for k, v in td.items(True) if is_non_tensor(v)]
    if bad:
        raise TypeError(f"save_memmap stores tensors only; non-tensor fields: {bad}")
    tmp = folder.with_name(folder.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    td.memmap(tmp)
    (tmp / MANIFEST).write_text(json.dumps(folder_manifest(tmp)))
    if folder.exists():
        shutil.rmtree(folder)
    os.replace(tmp, folder)
