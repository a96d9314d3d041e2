"""Atomic file outputs: a reader sees the old file or the new one, never half of one."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any, Iterator


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yields a temporary path beside ``path``; renames it into place if the block succeeds.

    Write the output to the yielded path with any writer (``torch.save``, ``savefig``,
    ``json.dump``...). The temporary name keeps ``path``'s suffix, so writers that pick a
    format from the extension (matplotlib) still do. On success the file is flushed to
    disk and ``os.replace``-d over ``path`` (atomic on POSIX file systems); on any error,
    ``KeyboardInterrupt`` included, it is removed and ``path`` is left as it was.

    Examples:
        >>> import tempfile
        >>> out = Path(tempfile.mkdtemp()) / "notes.txt"
        >>> with atomic_path(out) as tmp:
        ...     _ = tmp.write_text("done")
        >>> out.read_text(), sorted(p.name for p in out.parent.iterdir())
        ('done', ['notes.txt'])
    """
    path = Path(path)
    tmp = temp_path_beside(path)
    try:
        yield tmp
        # fsync before the rename: otherwise a power cut can leave the new name pointing
        # at an empty file on some file systems.
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def temp_path_beside(path: str | os.PathLike) -> Path:
    """A new, empty, hidden temp file in ``path``'s folder (created if missing).

    Hidden and unique: two writers never share one, globs over the folder (``*.json``) do
    not pick up a half-written file, and it keeps ``path``'s suffix for writers that pick
    a format from it. ``os.replace`` it over ``path`` once complete.

    Examples:
        >>> import tempfile
        >>> tmp = temp_path_beside(Path(tempfile.mkdtemp()) / "plot.png")
        >>> tmp.name.startswith(".plot.png."), tmp.suffix, tmp.stat().st_size
        (True, '.png', 0)
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.",
                               suffix=f".tmp{path.suffix}")
    os.close(fd)
    return Path(tmp)


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Writes ``text`` (UTF-8) to ``path`` atomically; returns ``path``.

    Examples:
        >>> import tempfile
        >>> write_text_atomic(Path(tempfile.mkdtemp()) / "a.txt", "hi").read_text()
        'hi'
    """
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def write_json_atomic(path: str | os.PathLike, payload: Any, **dumps_kwargs) -> Path:
    """Writes ``json.dumps(payload, indent=2, **dumps_kwargs)`` to ``path`` atomically.

    The payload is serialised before the file is touched, so an unserialisable value
    raises without creating anything.

    Examples:
        >>> import tempfile
        >>> path = write_json_atomic(Path(tempfile.mkdtemp()) / "r.json", {"return": 5})
        >>> json.loads(path.read_text())
        {'return': 5}
    """
    dumps_kwargs.setdefault("indent", 2)
    return write_text_atomic(path, json.dumps(payload, **dumps_kwargs))
