"""Checkpointed pipeline stages: finished stages are skipped on rerun, configs must match."""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import os
import signal
import sys
import threading
import time
import weakref
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

from simdist.utils.atomic import write_json_atomic
from simdist.utils.checkpoint import CorruptFileError, recovery_hint
from simdist.utils.folder_errors import FolderInUseError, RunFolderError
from simdist.utils.sealed import (RELATIVE_KEY, anchored_paths, check_seal, relative_paths,
                                  seal)

#: Config keys that say where a run writes, not what it computes: never compared, so the
#: same folder spelled ``out``, ``out/`` or ``/abs/out`` resumes the same run.
LOCATION_KEYS = ("output_dir", "out_dir", "outputs", "output")


def read_json(path: str | os.PathLike, what: str = "file", recovery: str | None = None) -> Any:
    """``json.loads`` of a file, failing with the file's name and how to recover.

    Args:
        path: the JSON file.
        what: what the file is, for the message (e.g. ``"stage record"``).
        recovery: what to do if it is corrupt (default: :func:`recovery_hint`).

    Raises:
        CorruptFileError: the file is not valid UTF-8 JSON (e.g. truncated by a crash or
            a full disk).
    """
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise CorruptFileError(f"{what} {str(path)!r} is corrupt (not valid JSON: {err}). "
                               f"To recover, {recovery or recovery_hint(path)}") from None


class StageRunner:
    """Runs a recipe's stages once each, under one output directory.

    ``run(name, fn)`` calls ``fn(stage_dir)`` unless ``<out>/stages/<name>.json`` exists,
    in which case the stored result is returned. A stage's result (a JSON-able dict) is
    written atomically only after ``fn`` returns, so a stage killed midway reruns (and can
    resume from whatever it checkpointed in its ``stage_dir``). The recipe config is saved
    as ``<out>/config.json``; rerunning into the same directory with a different config
    raises :class:`RunFolderError` instead of mixing results. ``runtime_keys`` name
    settings that change where or how fast the work runs but not its results (e.g.
    ``device``): they are saved, not compared, so a run started on one device can be
    resumed on another. ``location_keys`` (default :data:`LOCATION_KEYS`, e.g.
    ``output_dir``) are not compared either: a run's identity is what it computes, not how
    its folder is spelled.

    One run at a time: the runner holds an exclusive ``flock`` on ``<out>/.lock`` (with
    the holder's pid inside) for as long as it lives, and a second run into the same
    folder fails at once with :class:`FolderInUseError`, naming the folder and that pid.
    The kernel drops the lock when the holding process exits or is killed, so a crashed
    run never blocks its rerun. Runners of the same process share the lock, as do the
    workers of :func:`run_jobs`.

    Examples:
        >>> import tempfile
        >>> runner = StageRunner(tempfile.mkdtemp(), {"seed": 0})
        >>> runner.run("count", lambda d: {"n": 3})
        {'n': 3}
        >>> runner.run("count", lambda d: {"n": 99})  # finished: not run again
        {'n': 3}
        >>> runner.close()  # releases the folder's lock (also done when it is collected)
    """

    def __init__(self, out_dir: str | Path, config: Any, runtime_keys: Sequence[str] = (),
                 location_keys: Sequence[str] = LOCATION_KEYS):
        self.out = Path(out_dir)
        (self.out / "stages").mkdir(parents=True, exist_ok=True)
        # Lock before reading or writing anything: the other run may be writing config.json.
        key = _acquire_lock(self.out)
        self._release = weakref.finalize(self, _release_lock, key)
        try:
            self.config = self._check_config(config, set(runtime_keys) | set(location_keys))
        except BaseException:
            self.close()
            raise
        self.timings: dict[str, float] = {}

    def _check_config(self, config: Any, ignored: set[str]) -> dict:
        # a field added to the config after a folder was made reads as its default there
        defaults = field_defaults(config) if dataclasses.is_dataclass(config) else {}
        config = dataclasses.asdict(config) if dataclasses.is_dataclass(config) else config
        config = json.loads(json.dumps(config, default=str))
        saved = self.out / "config.json"
        if saved.exists():
            previous = read_json(saved, "run config", recovery=(
                f"delete {saved} and rerun with the settings this folder's results were "
                "made with (it is rewritten from them), or use another --output-dir"))
            if not isinstance(previous, dict):
                raise CorruptFileError(f"run config {str(saved)!r} is not a JSON object; "
                                       f"delete it and rerun with this folder's settings")
            previous = {**{k: v for k, v in defaults.items() if k not in previous}, **previous}
            changed = sorted(k for k in set(previous) | set(config)
                             if previous.get(k) != config.get(k) and k not in ignored)
            if changed:
                raise RunFolderError(f"{self.out} holds results of a different config (changed: "
                                 f"{changed}); use another --output-dir or the same settings")
        else:
            finished = sorted(p.stem for p in (self.out / "stages").glob("*.json"))
            if finished:  # their settings are unknown: refuse rather than guess them
                raise RunFolderError(
                    f"{self.out} has finished stages {finished} but no config.json, so "
                    "the settings they were made with are unknown. Restore config.json "
                    "(a results.json holds it under 'config'), or use another --output-dir")
            write_json_atomic(saved, config, default=str)
        return config

    def close(self) -> None:
        """Releases this runner's hold on the folder's lock (idempotent)."""
        self._release()

    def __enter__(self) -> StageRunner:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def stage_dir(self, name: str) -> Path:
        path = self.out / "stages" / name
        path.mkdir(parents=True, exist_ok=True)
        return path

    def done(self, name: str) -> bool:
        return (self.out / "stages" / f"{name}.json").exists()

    def run(self, name: str, fn: Callable[[Path], dict]) -> dict:
        record = self.out / "stages" / f"{name}.json"
        if record.exists():
            stored = read_stage_record(self.out, name)
            self.timings[name] = stored["seconds"]
            return stored["result"]
        start = time.perf_counter()
        result = fn(self.stage_dir(name))
        seconds = time.perf_counter() - start
        self.timings[name] = seconds
        write_stage_record(self.out, name, result, seconds)
        return result

    def result(self, name: str) -> dict:
        """The stored result of a finished stage (its timing is recorded too).

        Raises:
            KeyError: if the stage has not finished.
        """
        if not self.done(name):
            raise KeyError(f"stage {name!r} has not finished under {self.out}")
        return self.run(name, lambda d: {})


def write_stage_record(out: str | Path, name: str, result: dict, seconds: float) -> Path:
    """Writes ``<out>/stages/<name>.json`` atomically: the stage's result with every path
    inside ``out`` stored relative to it (the folder can be moved or copied) and a digest
    (a hand edit is refused when it is read back, see :mod:`simdist.utils.sealed`)."""
    out = Path(out)
    relative, places = relative_paths(json.loads(json.dumps(result, default=str)), out)
    payload = {"result": relative, "seconds": seconds, RELATIVE_KEY: places}
    return write_json_atomic(out / "stages" / f"{name}.json", seal(payload))


def read_stage_record(out: str | Path, name: str) -> dict:
    """``{"result", "seconds"}`` of a finished stage of the run folder ``out``: its digest
    checked, its paths under ``out`` wherever the folder is now.

    Raises:
        CorruptFileError: not JSON, or not a stage record.
        EditedRecordError: its contents do not match its digest.
    """
    return read_stage_file(Path(out) / "stages" / f"{name}.json")


def read_stage_file(path: str | Path) -> dict:
    """:func:`read_stage_record` of a record file given by its path (its run folder is the
    folder above ``stages/``; a record kept elsewhere, its own folder). A record without
    ``"seconds"`` (written by hand for a tool) reads as 0 seconds."""
    path = Path(path)
    out = path.parents[1] if path.parent.name == "stages" else path.parent
    name = path.stem
    stored = check_seal(read_json(path, f"record of stage {name!r}"), path, how=(
        f"Restore the original, or delete it (and the stages after {name!r}) so the run "
        "recomputes them."))
    if not (isinstance(stored, dict) and "result" in stored):
        raise CorruptFileError(f"record of stage {name!r} {str(path)!r} is incompatible (no "
                               f"'result'). To recover, {recovery_hint(path)}")
    return {"result": anchored_paths(stored["result"], out, stored.get(RELATIVE_KEY, [])),
            "seconds": stored.get("seconds", 0.0)}


# -- one run per folder ---------------------------------------------------------------------
# Locks this process holds: {resolved folder: [fd, number of runners using it]}.
_HELD: dict[str, list[int]] = {}
# Folders whose lock the parent process holds for us (we are one of its run_jobs workers).
_INHERITED: set[str] = set()
_LOCKS_GUARD = threading.Lock()


def _acquire_lock(out: Path) -> str:
    key = str(out.resolve())
    with _LOCKS_GUARD:
        if key in _HELD:
            _HELD[key][1] += 1
            return key
        if key in _INHERITED:
            return key
        try:
            import fcntl
        except ImportError:  # not POSIX: no locking
            return key
        path = out / ".lock"
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 64).decode(errors="replace").strip()
            os.close(fd)
            who = f"process {holder}" if holder.isdigit() else "another process"
            raise FolderInUseError(
                f"output folder {str(out)!r} is in use by another run ({who} holds "
                f"{str(path)!r}); wait for it to finish, stop it, or use another "
                "--output-dir") from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        _HELD[key] = [fd, 1]
        return key


def _release_lock(key: str) -> None:
    with _LOCKS_GUARD:
        held = _HELD.get(key)
        if held is None:
            return
        held[1] -= 1
        if held[1] == 0:
            del _HELD[key]
            os.close(held[0])  # closing the last descriptor drops the flock


# -- parallel jobs ---------------------------------------------------------------------------
def run_jobs(calls: Sequence[tuple[Callable, tuple]], jobs: int = 1,
             after: Sequence[Sequence[int]] | None = None, threads: int | None = None
             ) -> list:
    """Runs ``(fn, args)`` calls, ``jobs`` at a time; returns their results in order.

    ``after[i]`` lists the calls (earlier in ``calls``) that call ``i`` waits for, e.g. a
    student stage waits for its teacher's; ``None``: the calls are independent. Whenever a
    process is free, the first call in the list whose prerequisites have finished starts,
    so list order is the priority.

    ``jobs=1`` calls them here, in order. Otherwise each runs in one of ``jobs`` spawned
    worker processes (``fn`` must be importable: a module-level function), each with
    ``threads`` torch threads (default ``cpu_count // jobs``), so that e.g. two recipe
    stages that do not need each other's results share a 2-core machine instead of
    queueing. On an error, calls not yet started are cancelled, those running finish (a
    recipe stage keeps what it checkpointed), then the first error is raised.

    The workers are kept for the next call with the same ``jobs`` and ``threads`` (a
    fresh process spends seconds importing torch and MuJoCo; a recipe makes several such
    calls per run), so a call must not rely on a fresh process: each sets its own seeds.
    Workers die with this process: killing it (even with SIGKILL) leaves no orphans (on
    Linux the kernel signals them; elsewhere they notice within a second). A worker that
    dies (killed, out of memory) fails the run with ``BrokenProcessPool`` naming the calls
    that had not finished. Workers share this process's :class:`StageRunner` folder locks.

    Examples:
        >>> run_jobs([(pow, (2, 3)), (divmod, (7, 2))])
        [8, (3, 1)]
        >>> run_jobs([(pow, (2, 3)), (divmod, (7, 2)), (max, (1, 5))], jobs=2,
        ...          after=[(), (), (0, 1)])
        [8, (3, 1), 5]
    """
    results = dict(iter_jobs(calls, jobs, after, threads))
    return [results[i] for i in range(len(calls))]


def iter_jobs(calls: Sequence[tuple[Callable, tuple]], jobs: int = 1,
              after: Sequence[Sequence[int]] | None = None, threads: int | None = None
              ) -> Iterator[tuple[int, Any]]:
    """:func:`run_jobs` that yields ``(index, result)`` as each call finishes, so the
    caller can keep each result (e.g. write a dataset shard) before the next ones end.

    ``jobs=1`` runs each call here when the next result is asked for. Closing the
    generator early waits for the calls running in workers and starts no others.

    Examples:
        >>> list(iter_jobs([(pow, (2, 3)), (divmod, (7, 2))]))
        [(0, 8), (1, (3, 1))]
    """
    if jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs}")
    if threads is not None and threads < 1:
        raise ValueError(f"threads must be >= 1, got {threads}")
    after = [tuple(a) for a in after] if after is not None else [()] * len(calls)
    if len(after) != len(calls):
        raise ValueError(f"after has {len(after)} entries for {len(calls)} calls")
    for i, needs in enumerate(after):
        if any(not isinstance(j, int) or not 0 <= j < i for j in needs):
            raise ValueError(f"after[{i}] = {needs}: a call can only wait for calls "
                             f"listed before it (indices 0..{i - 1})")
    if jobs == 1 or len(calls) <= 1:
        for i, (fn, args) in enumerate(calls):
            yield i, fn(*args)
        return
    threads = threads or max(1, (os.cpu_count() or 1) // jobs)
    with _LOCKS_GUARD:
        locks = sorted(set(_HELD) | _INHERITED)
    pool = _worker_pool(jobs, threads)
    finished: set[int] = set()
    running: dict[Future, int] = {}
    waiting = list(range(len(calls)))
    try:
        while waiting or running:
            # fill free processes in list order; the pool's own queue stays empty, so a call
            # that becomes ready later still starts before those listed after it
            for i in [i for i in waiting if all(j in finished for j in after[i])]:
                if len(running) >= jobs:
                    break
                fn, args = calls[i]
                running[pool.submit(_call_in_worker, locks, fn, args)] = i
                waiting.remove(i)
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in done:
                i = running.pop(future)
                result = future.result()
                finished.add(i)
                yield i, result
    except BrokenProcessPool as err:
        _drop_worker_pool(pool)
        unfinished = [_describe(*calls[i]) for i in range(len(calls)) if i not in finished]
        raise BrokenProcessPool(
            f"a run_jobs worker process died abruptly (killed by a signal or the "
            f"out-of-memory killer?) while these calls had not finished: {unfinished}. "
            "Finished work is kept: rerun the same command to resume") from err
    except (Exception, GeneratorExit):
        wait(running)  # a call's error or an early close: let the running calls finish
        raise
    except BaseException:  # e.g. KeyboardInterrupt: stop the workers too
        _drop_worker_pool(pool)
        raise


# The workers of the last run_jobs call, kept for the next one with the same (jobs, threads,
# sys.path): a spawned worker imports with the sys.path its parent had when it started.
_POOL: dict[tuple, ProcessPoolExecutor] = {}


def _worker_pool(jobs: int, threads: int) -> ProcessPoolExecutor:
    key = (jobs, threads, tuple(sys.path))
    with _LOCKS_GUARD:
        pool = _POOL.get(key)
        if pool is not None:
            return pool
        for old in _POOL.values():  # one set of idle workers at most
            old.shutdown(wait=False)
        _POOL.clear()
        # spawn, not fork: forked children of a process that already ran torch/OpenMP or
        # opened a GL context can deadlock.
        pool = ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_init_worker, initargs=(threads, os.getpid()))
        _POOL[key] = pool
        return pool


def _drop_worker_pool(pool: ProcessPoolExecutor) -> None:
    with _LOCKS_GUARD:
        for key in [k for k, p in _POOL.items() if p is pool]:
            del _POOL[key]
    pool.shutdown(wait=True, cancel_futures=True)


def _call_in_worker(locks: Sequence[str], fn: Callable, args: tuple) -> Any:
    # The parent's folder locks as of this call (a kept worker may serve several runs).
    with _LOCKS_GUARD:
        _INHERITED.clear()
        _INHERITED.update(locks)
    return fn(*args)


def _describe(fn: Callable, args: tuple) -> str:
    """``name(arg, ...)`` with each argument's repr cut short (configs are long)."""
    shown = [r if len(r) <= 40 else r[:37] + "..." for r in map(repr, args)]
    return f"{getattr(fn, '__qualname__', repr(fn))}({', '.join(shown)})"


def _init_worker(threads: int, parent: int) -> None:
    _die_with_parent(parent)
    import torch
    torch.set_num_threads(threads)


def _die_with_parent(parent: int) -> None:
    """Makes this process exit when ``parent`` does, however the parent ends."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes
            libc = ctypes.CDLL(None, use_errno=True)
            PR_SET_PDEATHSIG = 1
            # SIGKILL: a worker stuck in native code (torch, MuJoCo) must still go.
            libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):
            pass  # the watchdog below still works
    if os.getppid() != parent:  # the parent died before prctl took effect
        os._exit(1)

    # Fallback where prctl is unavailable (macOS): poll the parent pid once a second. An
    # orphan is re-parented, so its parent pid changes.
    def watch():
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, name="simdist-parent-watchdog", daemon=True).start()


#: Field metadata key: the value a run folder saved before the field existed was made with,
#: when that is not the field's (new) default. E.g. a field that switches a behaviour on
#: by default: ``field(default=True, metadata={ABSENT_MEANS: False})``, so an older folder
#: is refused under the new default instead of resuming as if it had been made with it.
ABSENT_MEANS = "absent_means"


def field_defaults(config: Any) -> dict:
    """What each field of dataclass ``config`` reads as in a folder saved before the field
    existed: its ``ABSENT_MEANS`` metadata, else its plain (JSON) default."""
    out = {}
    for f in dataclasses.fields(config):
        if ABSENT_MEANS in f.metadata:
            out[f.name] = f.metadata[ABSENT_MEANS]
        elif f.default is not dataclasses.MISSING:
            out[f.name] = f.default
        elif f.default_factory is not dataclasses.MISSING:
            out[f.name] = f.default_factory()
    return json.loads(json.dumps(out, default=str))
