"""Run a recipe, SIGKILL it when a file appears (i.e. inside a given stage), rerun it."""

import os
import signal
import subprocess
import time
from pathlib import Path


def run_killed_when(command: list[str], marker: Path, timeout: float = 300) -> bool:
    """Starts ``command`` and SIGKILLs its whole process group as soon as ``marker``
    exists; returns whether the kill happened (False: the run finished first)."""
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    deadline = time.monotonic() + timeout
    try:
        while proc.poll() is None and time.monotonic() < deadline:
            if marker.exists():
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
                return True
            time.sleep(0.01)
        return False
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
