"""The records kept in results/ still rebuild their README tables with today's code."""

import importlib.util
import json
import shutil
from pathlib import Path

import pytest

from tests.in_process import run_script

ROOT = Path(__file__).resolve().parents[1]


def test_twist_cheetah_run_records_rebuild_without_training(tmp_path, capsys):
    kept = ROOT / "results" / "twist_cheetah_run_2026-12-02"
    out = tmp_path / "run"
    shutil.copytree(kept, out)
    # the command of results/README.md (--jobs 1: nothing is left to run in parallel; the
    # run was made when "auto" was the default, which on cheetah-run is the CNN student)
    done = run_script(ROOT / "recipes" / "twist_dmc.py", "--tasks", "cheetah-run", "--seeds",
                      0, 1, 2, 3, 4, "--no-baselines", "--no-record", "--jobs", 1,
                      "--student-readout", "auto", "--output-dir", out, capsys=capsys)
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("already done") == 30  # 6 stages x 5 seeds: nothing trained
    rebuilt = json.loads((out / "results.json").read_text())
    original = json.loads((kept / "results.json").read_text())
    assert rebuilt["results"] == original["results"]
    twist = rebuilt["summary"]["cheetah-run"]["TWIST (student)"]
    assert round(100 * twist["normalised"]) == 86  # the README's figure
    assert (out / "returns.png").stat().st_size > 0


def test_twist_faithful_cartpole_records_rebuild_the_readmes_figure(tmp_path, capsys):
    """TWIST's cartpole-balance row (the default CNN student, three seeds) from its
    records alone: nothing trained, the same table, 31% of the Oracle."""
    kept = ROOT / "results" / "twist_cartpole_faithful_3seeds_2026-12-07"
    out = tmp_path / "run"
    shutil.copytree(kept, out)
    done = run_script(ROOT / "recipes" / "twist_dmc.py", "--seeds", 0, 1, 2, "--students",
                      "twist", "--no-baselines", "--no-record", "--jobs", 1, "--output-dir",
                      out, capsys=capsys)
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("already done") == 12  # 4 stages x 3 seeds: nothing trained
    rebuilt = json.loads((out / "results.json").read_text())
    assert rebuilt["results"] == json.loads((kept / "results.json").read_text())["results"]
    twist = rebuilt["summary"]["cartpole-balance"]["TWIST (student)"]
    assert round(100 * twist["normalised"]) == 31  # the README's figure
    assert twist["seeds"] == 3


def _compare_runs():
    spec = importlib.util.spec_from_file_location("compare_runs",
                                                  ROOT / "experiments" / "compare_runs.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.main


def test_compare_runs_pairs_the_residual_records_by_episode(capsys):
    main = _compare_runs()
    logit = ROOT / "results" / "simdist_residual_logit_3seeds_2026-12-03"
    additive = ROOT / "results" / "simdist_residual_additive_3seeds_2026-12-03"
    main(["--run", str(logit), "--against", str(additive), "--names", "logit", "additive"])
    rows = capsys.readouterr().out.splitlines()
    # README Results: logit minus additive +19 / +19 / +23 points at 0 / 2 / 8 minutes
    paired = [row for row in rows if row.startswith("additive ")][-1]  # after the table's
    assert paired.split()[:4] == ["additive", "+19", "[", "+10,"]
    assert "+23 [  +14,   +32]" in paired
    # ...and by seed (README: every seed higher at 8 minutes, +44 / +16 / +7), the interval
    # over seeds spanning the seeds' means
    assert rows[-4].startswith("logit minus additive by seed")
    assert rows[-1].split() == ["8.00", "min:", "+44", "/", "+16", "/", "+7;", "+23",
                                "[+7,", "+44]"]


def test_compare_runs_seed_differences_match_hand_computed_means():
    from tests.in_process import benchmark_module
    seed_differences = benchmark_module("compare_runs").seed_differences
    point = lambda f: {"fraction": f, "seed_episodes": [2, 2, 2]}  # noqa: E731
    curves = {"minutes": [8.0], "A": [point([.5, .7, .4, .4, .9, .7])],
              "B": [point([.4, .6, .4, .4, .6, .6])]}
    row = seed_differences(curves, ("A", "B"))[0]
    assert row["seeds"] == pytest.approx([10.0, 0.0, 20.0])
    assert row["mean"] == pytest.approx(10.0)
    # three seeds: the cluster bootstrap's extremes are all-seed-1 and all-seed-2 draws
    assert 0.0 <= row["low"] <= row["mean"] <= row["high"] <= 20.0
    one_seed = {"minutes": [8.0], "A": [{"fraction": [.5, .7]}], "B": [{"fraction": [.4, .6]}]}
    assert seed_differences(one_seed, ("A", "B")) is None


def test_compare_runs_refuses_runs_of_other_worlds():
    main = _compare_runs()
    logit = ROOT / "results" / "simdist_residual_logit_3seeds_2026-12-03"
    one_seed = ROOT / "results" / "simdist_residual_additive_3seeds_2026-12-03" / "seed_0"
    with pytest.raises(SystemExit, match="not the same worlds"):
        main(["--run", str(logit), "--against", str(one_seed)])
