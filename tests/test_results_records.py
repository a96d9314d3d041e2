"""The records kept in results/ still rebuild their README tables with today's code."""

import json
import shutil
from pathlib import Path

from tests.in_process import run_script

ROOT = Path(__file__).resolve().parents[1]


def test_twist_cheetah_run_records_rebuild_without_training(tmp_path, capsys):
    kept = ROOT / "results" / "twist_cheetah_run_2026-12-02"
    out = tmp_path / "run"
    shutil.copytree(kept, out)
    # the command of results/README.md (--jobs 1: nothing is left to run in parallel)
    done = run_script(ROOT / "recipes" / "twist_dmc.py", "--tasks", "cheetah-run", "--seeds",
                      0, 1, 2, 3, 4, "--no-baselines", "--no-record", "--jobs", 1, "--output-dir",
                      out, capsys=capsys)
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("already done") == 30  # 6 stages x 5 seeds: nothing trained
    rebuilt = json.loads((out / "results.json").read_text())
    original = json.loads((kept / "results.json").read_text())
    assert rebuilt["results"] == original["results"]
    twist = rebuilt["summary"]["cheetah-run"]["TWIST (student)"]
    assert round(100 * twist["normalised"]) == 86  # the README's figure
    assert (out / "returns.png").stat().st_size > 0
