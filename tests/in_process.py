"""Run a recipe or benchmark script inside the test process, as ``python script args`` would.

A fresh interpreter spends ~10 s importing torch, TorchRL, dm_control and the rest on a
2-core machine before a script does anything; the tests that only check how a script
parses its flags, refuses bad values or reads a finished run need not pay that each time.
The end-to-end tests that exercise the command line itself (exit status, worker
processes, SIGKILL and resume) still start real subprocesses.
"""

import runpy
import sys
from dataclasses import dataclass
from pathlib import Path

import torch


@dataclass
class Finished:
    """What a finished script left: like :class:`subprocess.CompletedProcess`."""

    returncode: int
    stdout: str
    stderr: str


def run_script(path: Path, *args, capsys) -> Finished:
    """Executes ``path`` as ``__main__`` with ``sys.argv = [path, *args]``.

    ``SystemExit`` becomes the exit status the interpreter would give: ``None`` is 0, an
    integer is itself, anything else is printed to stderr with status 1. Torch's thread
    count is restored afterwards (scripts set their own).
    """
    capsys.readouterr()  # only this script's output
    argv, threads = sys.argv, torch.get_num_threads()
    sys.argv = [str(path), *map(str, args)]
    code = 0
    try:
        runpy.run_path(str(path), run_name="__main__")
    except SystemExit as exit_:
        if exit_.code is None or isinstance(exit_.code, int):
            code = exit_.code or 0
        else:
            print(exit_.code, file=sys.stderr)
            code = 1
    finally:
        sys.argv = argv
        torch.set_num_threads(threads)
    out, err = capsys.readouterr()
    return Finished(code, out, err)


def script_path(name: str) -> Path:
    """``benchmarks/<name>.py`` or ``experiments/<name>.py``, whichever holds the script."""
    root = Path(__file__).resolve().parents[1]
    for folder in ("benchmarks", "experiments"):
        if (root / folder / f"{name}.py").exists():
            return root / folder / f"{name}.py"
    raise FileNotFoundError(f"no script {name}.py in benchmarks/ or experiments/")


def benchmark_module(name: str):
    """A script of ``benchmarks/`` or ``experiments/`` imported as a module (the scripts
    are not a package)."""
    import importlib.util
    spec = importlib.util.spec_from_file_location(name, script_path(name))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
