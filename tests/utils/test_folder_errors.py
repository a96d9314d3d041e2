"""A folder the user cannot reuse ends a recipe with an ``error:`` line, not a traceback."""

from pathlib import Path

import pytest

from simdist.utils import FolderInUseError, RunFolderError, StageRunner
from simdist.utils.cli import exit_on_folder_errors

from tests.in_process import run_script

RECIPES = Path(__file__).resolve().parents[2] / "recipes"


def test_another_configs_folder_exits_with_status_2_and_the_reason(tmp_path, capsys):
    StageRunner(tmp_path, {"seed": 0, "episodes": 8}).close()
    with pytest.raises(SystemExit) as info, exit_on_folder_errors("demo.py"):
        StageRunner(tmp_path, {"seed": 0, "episodes": 3})
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(f"demo.py: error: {tmp_path} holds results of a different config "
                          "(changed: ['episodes'])")
    assert isinstance(info.value.__cause__, RunFolderError)
    assert issubclass(RunFolderError, ValueError)  # code that caught ValueError still does
    assert issubclass(FolderInUseError, RuntimeError)


def test_other_errors_pass_through_unchanged():
    # a bug is not a folder problem: it keeps its traceback
    with pytest.raises(KeyError), exit_on_folder_errors("demo.py"):
        raise KeyError("bug")
    with pytest.raises(ValueError, match="not a folder"), exit_on_folder_errors("demo.py"):
        raise ValueError("not a folder")


def test_dataset_recipe_refuses_another_configs_dataset_cleanly(tmp_path, capsys):
    args = ("--episodes", 2, "--shard-episodes", 2, "--steps", 4, "--out", tmp_path)
    first = run_script(RECIPES / "generate_dataset.py", *args, capsys=capsys)
    assert first.returncode == 0, first.stderr
    again = run_script(RECIPES / "generate_dataset.py", *args[:-2], "--seed", 1,
                       "--out", tmp_path, capsys=capsys)
    assert again.returncode == 2 and "Traceback" not in again.stderr
    assert "error: " in again.stderr and "holds a dataset generated with a different config" \
        in again.stderr
