"""Checkpointed pipeline stages: finished stages are skipped on rerun, configs must match."""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any, Callable, Sequence


def _atomic_json(path: Path, payload: Any) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(payload, indent=2, default=str))
    tmp.replace(path)


class StageRunner:
    """Runs a recipe's stages once each, under one output directory.

    ``run(name, fn)`` calls ``fn(stage_dir)`` unless ``<out>/stages/<name>.json`` exists,
    in which case the stored result is returned. A stage's result (a JSON-able dict) is
    written atomically only after ``fn`` returns, so a stage killed midway reruns (and can
    resume from whatever it checkpointed in its ``stage_dir``). The recipe config is saved
    as ``<out>/config.json``; rerunning into the same directory with a different config
    raises instead of mixing results. ``runtime_keys`` name settings that change where or
    how fast the work runs but not its results (e.g. ``device``): they are saved, not
    compared, so a run started on one device can be resumed on another.

    Examples:
        >>> import tempfile
        >>> runner = StageRunner(tempfile.mkdtemp(), {"seed": 0})
        >>> runner.run("count", lambda d: {"n": 3})
        {'n': 3}
        >>> runner.run("count", lambda d: {"n": 99})  # finished: not run again
        {'n': 3}
    """

    def __init__(self, out_dir: str | Path, config: Any, runtime_keys: Sequence[str] = ()):
        self.out = Path(out_dir)
        (self.out / "stages").mkdir(parents=True, exist_ok=True)
        config = dataclasses.asdict(config) if dataclasses.is_dataclass(config) else config
        config = json.loads(json.dumps(config, default=str))
        saved = self.out / "config.json"
        if saved.exists():
            previous = json.loads(saved.read_text())
            changed = sorted(k for k in set(previous) | set(config)
                             if previous.get(k) != config.get(k) and k not in runtime_keys)
            if changed:
                raise ValueError(f"{self.out} holds results of a different config (changed: "
                                 f"{changed}); use another --output-dir or the same settings")
        else:
            _atomic_json(saved, config)
        self.config = config
        self.timings: dict[str, float] = {}

    def stage_dir(self, name: str) -> Path:
        path = self.out / "stages" / name
        path.mkdir(parents=True, exist_ok=True)
        return path

    def done(self, name: str) -> bool:
        return (self.out / "stages" / f"{name}.json").exists()

    def run(self, name: str, fn: Callable[[Path], dict]) -> dict:
        record = self.out / "stages" / f"{name}.json"
        if record.exists():
            stored = json.loads(record.read_text())
            self.timings[name] = stored["seconds"]
            return stored["result"]
        start = time.perf_counter()
        result = fn(self.stage_dir(name))
        seconds = time.perf_counter() - start
        self.timings[name] = seconds
        _atomic_json(record, {"result": result, "seconds": seconds})
        return result

    def result(self, name: str) -> dict:
        """The stored result of a finished stage (its timing is recorded too).

        Raises:
            KeyError: if the stage has not finished.
        """
        if not self.done(name):
            raise KeyError(f"stage {name!r} has not finished under {self.out}")
        return self.run(name, lambda d: {})


def run_jobs(calls: Sequence[tuple[Callable, tuple]], jobs: int = 1) -> list:
    """Runs independent ``(fn, args)`` calls, ``jobs`` at a time; returns their results in order.

    ``jobs=1`` calls them here, in order. Otherwise each runs in one of ``jobs`` spawned
    worker processes (``fn`` must be importable: a module-level function), each with
    ``cpu_count // jobs`` torch threads, so that e.g. two recipe stages that do not need
    each other's results share a 2-core machine instead of queueing. On an error, calls not
    yet started are cancelled, those running finish (a recipe stage keeps what it
    checkpointed), then the first error is raised.

    Examples:
        >>> run_jobs([(pow, (2, 3)), (divmod, (7, 2))])
        [8, (3, 1)]
        >>> run_jobs([(pow, (2, 3)), (divmod, (7, 2))], jobs=2)
        [8, (3, 1)]
    """
    if jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs}")
    if jobs == 1 or len(calls) <= 1:
        return [fn(*args) for fn, args in calls]
    threads = max(1, (os.cpu_count() or 1) // jobs)
    # spawn, not fork: forked children of a process that already ran torch/OpenMP or
    # opened a GL context can deadlock.
    pool = ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_init_worker, initargs=(threads,))
    try:
        futures = [pool.submit(fn, *args) for fn, args in calls]
        return [future.result() for future in futures]
    except BaseException:
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    finally:
        pool.shutdown(wait=True)


def _init_worker(threads: int) -> None:
    import torch
    torch.set_num_threads(threads)
