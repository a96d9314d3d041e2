"""A finished run's records without its weights and data: what its tables are made of.

A recipe's stage records (``stages/<name>.json``: every evaluation episode's figures) and
its ``config.json`` are all that its table, plot and ``results.json`` are computed from:
rerunning the recipe into a folder that holds only them reuses every stage and rebuilds
the outputs without training anything. They are a few KB per seed, so the records of a
published figure can be kept in git (``results/`` in this repository) long after the
checkpoints and datasets are gone, and a later run, on another day or machine, can add
seeds beside them: the tables then pool old and new seeds' episodes.

Usage::

    python -m simdist.utils.records RUN_DIR DEST_DIR
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

#: the files of a run folder (and of each of its ``seed_<n>/`` folders) that are records
RUN_FILES = ("config.json", "results.json")


def record_files(run: str | Path) -> list[Path]:
    """The record files of ``run``, relative to it: ``config.json``, ``results.json`` and
    ``stages/*.json`` of the folder and of each ``seed_<n>/`` folder in it (the SimDist
    recipe's multi-seed layout). Stage folders (weights, data, logs) are not records.

    Raises:
        FileNotFoundError: ``run`` has no ``config.json`` (no seed folder has one either),
            i.e. it is not a recipe's output folder.
    """
    run = Path(run)
    folders = [run, *sorted(p for p in run.glob("seed_*") if p.is_dir())]
    files = [f for folder in folders for f in
             [*(folder / name for name in RUN_FILES), *sorted((folder / "stages").glob("*.json"))]
             if f.is_file()]
    if not any(f.name == "config.json" for f in files):
        raise FileNotFoundError(f"{str(run)!r} is not a recipe's output folder: no "
                                "config.json in it or in a seed_<n>/ folder")
    return [f.relative_to(run) for f in files]


def copy_records(run: str | Path, dest: str | Path) -> list[Path]:
    """Copies the record files of ``run`` (:func:`record_files`) into ``dest``, keeping
    their relative paths; returns the copied paths under ``dest``.

    Refuses to overwrite a record in ``dest`` that differs from the one in ``run``: the
    two folders would then hold different runs' results under one name.

    Examples:
        >>> import json, tempfile
        >>> run, dest = Path(tempfile.mkdtemp()), Path(tempfile.mkdtemp()) / "kept"
        >>> (run / "stages" / "big").mkdir(parents=True)
        >>> _ = (run / "config.json").write_text(json.dumps({"seed": 0}))
        >>> _ = (run / "stages" / "eval.json").write_text(json.dumps({"result": [1, 2]}))
        >>> _ = (run / "stages" / "big" / "weights.pt").write_bytes(b"not a record")
        >>> [str(p.relative_to(dest)) for p in copy_records(run, dest)]
        ['config.json', 'stages/eval.json']
    """
    run, dest = Path(run), Path(dest)
    copied = []
    for relative in record_files(run):
        source, target = run / relative, dest / relative
        if target.exists() and target.read_bytes() != source.read_bytes():
            raise FileExistsError(f"{str(target)!r} already holds a different record than "
                                  f"{str(source)!r}; copy into another folder")
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source, target)
        copied.append(target)
    return copied


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m simdist.utils.records",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("run", help="a recipe's output folder")
    parser.add_argument("dest", help="where to copy its records")
    args = parser.parse_args(argv)
    try:
        copied = copy_records(args.run, args.dest)
    except (FileNotFoundError, FileExistsError) as error:
        parser.error(str(error))
    size = sum(p.stat().st_size for p in copied)
    print(f"copied {len(copied)} record files ({size / 1e3:.0f} KB) to {args.dest}")


if __name__ == "__main__":
    main()
