"""One run per folder, workers that die with their parent, folder spelling (issue 18, 7-9)."""

import os
import signal
import subprocess
import sys
import textwrap
import time
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import pytest

from simdist.utils import FolderInUseError, StageRunner, run_jobs

# Importable by spawned workers (they get the parent's sys.path).
HELPERS = '''
import os, signal, time
from pathlib import Path

def hang(folder):
    Path(folder, f"worker_{os.getpid()}").touch()
    time.sleep(120)

def die():
    os.kill(os.getpid(), signal.SIGKILL)

def nap(seconds):
    time.sleep(seconds)
    return seconds

def pid_after(seconds):
    time.sleep(seconds)
    return os.getpid()

def use_runner(out):
    from simdist.utils import StageRunner
    with StageRunner(out, {"seed": 0}) as runner:
        return runner.run(f"in_{os.getpid()}", lambda d: {"pid": os.getpid()})["pid"]
'''


@pytest.fixture
def helpers(tmp_path, monkeypatch):
    (tmp_path / "hardening_helpers.py").write_text(HELPERS)
    monkeypatch.syspath_prepend(str(tmp_path))
    import hardening_helpers
    yield hardening_helpers
    sys.modules.pop("hardening_helpers", None)


def _wait_for(condition, timeout=60.0, what="condition"):
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.1)


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] not in ("Z", "X")  # zombies are dead
    except FileNotFoundError:
        return False


def _python(script: str, **kwargs) -> subprocess.Popen:
    kwargs = {"stdout": subprocess.PIPE, "stderr": subprocess.PIPE, "text": True, **kwargs}
    return subprocess.Popen([sys.executable, "-c", textwrap.dedent(script)], **kwargs)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_sigkill_of_the_parent_leaves_no_worker_running(tmp_path, helpers):
    parent = _python(f"""
        import sys
        sys.path.insert(0, {str(tmp_path)!r})
        from hardening_helpers import hang
        from simdist.utils import run_jobs
        run_jobs([(hang, ({str(tmp_path)!r},)), (hang, ({str(tmp_path)!r},))], jobs=2)
    """, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        _wait_for(lambda: len(list(tmp_path.glob("worker_*"))) == 2 or parent.poll() is not None,
                  what="two workers")
        assert parent.poll() is None, "the parent ended early"
        workers = [int(p.name.split("_")[1]) for p in tmp_path.glob("worker_*")]
        assert all(_alive(pid) for pid in workers)
        parent.kill()  # SIGKILL: no Python cleanup runs in the parent
        parent.wait()
        _wait_for(lambda: not any(_alive(pid) for pid in workers), timeout=10,
                  what="the workers to die with their parent")
    finally:
        parent.kill()
        parent.wait()
        for p in tmp_path.glob("worker_*"):
            try:
                os.kill(int(p.name.split("_")[1]), signal.SIGKILL)
            except ProcessLookupError:
                pass


def test_a_killed_worker_fails_the_run_naming_the_unfinished_call(helpers):
    with pytest.raises(BrokenProcessPool, match=r"died abruptly.*die\(\)") as info:
        run_jobs([(helpers.nap, (0.0,)), (helpers.die, ())], jobs=2)
    assert "nap(0.0)" not in str(info.value)  # it had finished
    assert "rerun the same command" in str(info.value)


def test_workers_are_kept_for_the_next_call_and_replaced_after_one_dies(tmp_path, helpers):
    # both busy at once: one call per worker (2 s: a worker spawned late under load must
    # still find the other busy, else one worker takes both calls)
    calls = [(helpers.pid_after, (2.0,))] * 2
    first = set(run_jobs(calls, jobs=2, threads=1))
    assert len(first) == 2 and os.getpid() not in first
    assert set(run_jobs(calls, jobs=2, threads=1)) == first  # no new processes
    # The kept workers use the folder locks the parent holds at each call, not at their start.
    for name in ("a", "b"):
        with StageRunner(tmp_path / name, {"seed": 0}) as runner:
            pids = run_jobs([(helpers.use_runner, (str(tmp_path / name),))] * 2, jobs=2,
                            threads=1)
            assert set(pids) <= first and runner.done(f"in_{pids[0]}")
    with pytest.raises(BrokenProcessPool):
        run_jobs([(helpers.die, ())] * 2, jobs=2, threads=1)
    assert not set(run_jobs(calls, jobs=2, threads=1)) & first  # a fresh pool


def test_a_second_run_into_the_same_folder_is_refused_until_the_first_dies(tmp_path):
    out = tmp_path / "out"
    first = _python(f"""
        import time
        from simdist.utils import StageRunner
        runner = StageRunner({str(out)!r}, {{"seed": 0}})
        print("locked", flush=True)
        time.sleep(120)
    """)
    try:
        assert first.stdout.readline().strip() == "locked", first.communicate()
        with pytest.raises(FolderInUseError, match=f"in use by another run \\(process {first.pid} ") \
                as info:
            StageRunner(out, {"seed": 0})
        assert str(out) in str(info.value)
        first.kill()  # a crash: the kernel releases the lock
        first.wait()
        with StageRunner(out, {"seed": 0}) as runner:
            assert runner.run("a", lambda d: {"ok": 1}) == {"ok": 1}
            assert (out / ".lock").read_text().strip() == str(os.getpid())
    finally:
        first.kill()
        first.communicate()  # closes the pipes


def test_runners_of_one_run_share_its_lock(tmp_path, helpers):
    with StageRunner(tmp_path, {"seed": 0}) as runner:
        with StageRunner(tmp_path / ".", {"seed": 0}):  # same process: shared
            pass
        pids = run_jobs([(helpers.use_runner, (str(tmp_path),))] * 2, jobs=2)  # its workers
        assert os.getpid() not in pids and runner.done(f"in_{pids[0]}")
    # Released once the last runner closes: another process may now take the folder.
    check = subprocess.run([sys.executable, "-c", "import fcntl, os; fcntl.flock(os.open("
                            f"{str(tmp_path / '.lock')!r}, os.O_RDWR), "
                            "fcntl.LOCK_EX | fcntl.LOCK_NB)"], capture_output=True, text=True)
    assert check.returncode == 0, check.stderr


def test_the_folder_may_be_spelled_differently_but_the_config_may_not_change(tmp_path,
                                                                             monkeypatch):
    monkeypatch.chdir(tmp_path)
    StageRunner("out", {"seed": 1, "output_dir": "out"}).close()
    for spelling in ("out/", "out//", "./out", str(tmp_path / "out")):
        StageRunner(spelling, {"seed": 1, "output_dir": spelling}).close()
    with pytest.raises(ValueError, match="changed: \\['seed'\\]"):
        StageRunner(Path("out"), {"seed": 2, "output_dir": "out/"})
    # location_keys is a parameter: a recipe naming its folder otherwise can say so.
    StageRunner("b", {"seed": 1, "where": "b"}, location_keys=("where",)).close()
    StageRunner("b/", {"seed": 1, "where": "b/"}, location_keys=("where",)).close()
