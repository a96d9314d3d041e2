"""Run records that survive a move and notice an edit.

A run folder's stage records and ``results.json`` are what every later stage, table and
plot is computed from. Two things could make them lie:

- **a move**: a record that stores ``/home/me/runs/a/stages/pretrain/agent.pt`` makes a
  copy of the folder silently read the original's weights. :func:`relative_paths` stores
  every path that lies inside the run folder relative to it (and lists where), and
  :func:`anchored_paths` puts them back under wherever the folder now is.
- **a hand edit**: :func:`seal` adds the SHA-256 of the record's canonical JSON;
  :func:`check_seal` refuses a record whose contents no longer match it, naming the file.
  Records written before seals existed (no digest) are read as they are.

Examples:
    >>> record = seal({"result": {"return": 912.5}})
    >>> check_seal(record, "stages/zero_shot.json")["result"]
    {'return': 912.5}
    >>> record["result"]["return"] = 990.0
    >>> try:
    ...     check_seal(record, "stages/zero_shot.json")
    ... except EditedRecordError as err:
    ...     print(str(err).split(":")[0])
    stages/zero_shot.json was changed after the run wrote it
"""

from __future__ import annotations

import copy
import hashlib
import json
import os
from pathlib import Path
from typing import Any

from simdist.utils.folder_errors import RunFolderError

#: Key of a record's digest: the SHA-256 of the rest of the record's canonical JSON.
DIGEST_KEY = "sha256"
#: Key of a record's list of places (key paths) that hold paths relative to the run folder.
RELATIVE_KEY = "run_relative"


class EditedRecordError(RunFolderError):
    """A sealed record whose contents no longer match its digest (edited by hand, or
    corrupted): the run refuses it rather than report or reuse figures it did not compute.
    A :class:`RunFolderError`, so the recipes end with exit status 2 and the message.

    Examples:
        >>> record = seal({"result": 1.0})
        >>> try:
        ...     check_seal({**record, "result": 2.0}, "stages/x.json")
        ... except EditedRecordError as err:
        ...     print(isinstance(err, RunFolderError))
        True
    """


def digest(payload: Any) -> str:
    """SHA-256 of ``payload``'s canonical JSON (sorted keys, no spaces)."""
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def seal(payload: dict) -> dict:
    """``payload`` (as JSON would store it) with its digest under :data:`DIGEST_KEY`."""
    plain = json.loads(json.dumps({k: v for k, v in payload.items() if k != DIGEST_KEY},
                                  default=str))
    return {**plain, DIGEST_KEY: digest(plain)}


def check_seal(record: Any, path: str | os.PathLike, how: str = "") -> Any:
    """``record`` without its digest, after checking the digest matches.

    Args:
        record: a parsed JSON record (one without a digest predates seals: returned as is).
        path: the record's file, for the message.
        how: what to do about an edited record (default: restore or delete it).

    Raises:
        EditedRecordError: the digest does not match the contents.
    """
    if not isinstance(record, dict) or DIGEST_KEY not in record:
        return record
    body = {k: v for k, v in record.items() if k != DIGEST_KEY}
    if digest(body) != record[DIGEST_KEY]:
        raise EditedRecordError(
            f"{path} was changed after the run wrote it: its contents no longer match "
            f"its {DIGEST_KEY} digest, so its figures are not what the run computed. "
            + (how or "Restore the original, or delete the file so the run recomputes it."))
    return body


def relative_paths(value: Any, root: str | os.PathLike) -> tuple[Any, list[list]]:
    """``value`` with every string naming an existing file or folder inside ``root``
    replaced by its path relative to ``root``, and the key paths where that was done.

    Only strings with a path separator are considered, so words such as ``"foam"`` stay
    words even when ``root`` is the working directory.

    Examples:
        >>> import tempfile
        >>> root = Path(tempfile.mkdtemp())
        >>> (root / "stages").mkdir()
        >>> relative_paths({"path": str(root / "stages"), "target": "foam"}, root)
        ({'path': 'stages', 'target': 'foam'}, [['path']])
    """
    base = Path(root).resolve()
    found: list[list] = []

    def walk(node, where):
        if isinstance(node, dict):
            return {k: walk(v, where + [k]) for k, v in node.items()}
        if isinstance(node, (list, tuple)):
            return [walk(v, where + [i]) for i, v in enumerate(node)]
        if isinstance(node, str) and os.sep in node and Path(node).exists():
            resolved = Path(node).resolve()
            if resolved == base or base in resolved.parents:
                found.append(where)
                return resolved.relative_to(base).as_posix()
        return node

    return walk(value, []), found


def anchored_paths(value: Any, root: str | os.PathLike, places: list[list]) -> Any:
    """The inverse of :func:`relative_paths`: each place's relative path joined to
    ``root`` (the run folder where it is now).

    Examples:
        >>> anchored_paths({"path": "stages/pretrain/agent.pt"}, "/runs/copy", [["path"]])
        {'path': '/runs/copy/stages/pretrain/agent.pt'}
    """
    value = copy.deepcopy(value)
    for where in places:
        if not where:
            return str(Path(root) / value)
        node = value
        for key in where[:-1]:
            node = node[key]
        node[where[-1]] = str(Path(root) / node[where[-1]])
    return value


def write_run_json(path: str | os.PathLike, payload: dict, run: str | os.PathLike,
                   as_given: tuple[str, ...] = ("config",)) -> Path:
    """Writes ``payload`` (e.g. a run's ``results.json``) atomically, relocatable and
    sealed: paths inside the run folder ``run`` stored relative to it (their places under
    :data:`RELATIVE_KEY`) and the digest under :data:`DIGEST_KEY`. Top-level keys in
    ``as_given`` are stored as they are (a config says what the user typed).

    Examples:
        >>> import tempfile
        >>> run = Path(tempfile.mkdtemp())
        >>> _ = write_run_json(run / "results.json", {"return": 912.5}, run)
        >>> read_run_json(run / "results.json")
        {'return': 912.5}
    """
    from simdist.utils.atomic import write_json_atomic

    plain = json.loads(json.dumps(payload, default=str))
    walked = {k: v for k, v in plain.items() if k not in as_given}
    relative, places = relative_paths(walked, run)
    stored = {k: relative.get(k, v) for k, v in plain.items()}
    return write_json_atomic(path, seal({**stored, RELATIVE_KEY: places}))


def read_run_json(path: str | os.PathLike, run: str | os.PathLike | None = None) -> dict:
    """A file :func:`write_run_json` wrote (or an older one without digest), its digest
    checked and its paths joined to ``run`` (default: the file's folder).

    Raises:
        CorruptFileError: not valid JSON.
        EditedRecordError: its contents do not match its digest.
    """
    from simdist.utils.stages import read_json

    path = Path(path)
    stored = check_seal(read_json(path, "run record"), path, how=(
        "Restore the original, or delete it: the recipe writes it again from the stage "
        "records when rerun."))
    if not isinstance(stored, dict):
        return stored
    places = stored.pop(RELATIVE_KEY, [])
    return anchored_paths(stored, path.parent if run is None else run, places)
