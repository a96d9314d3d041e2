"""Run folders can be moved, and notice hand edits (simdist.utils.sealed, StageRunner)."""

import dataclasses
import json
import os
import shutil

import pytest

from simdist.utils import RunFolderError, StageRunner
from simdist.utils.cli import ConfigError, config_file
from simdist.utils.sealed import (DIGEST_KEY, EditedRecordError, read_run_json, seal,
                                  write_run_json)
from simdist.utils.stages import read_stage_record


def _weights_stage(d):
    (d / "agent.pt").write_bytes(b"weights")
    return {"path": str(d / "agent.pt"), "files": [str(d / "agent.pt")], "target": "foam"}


def test_a_copied_folder_reads_its_own_files_not_the_originals(tmp_path):
    original, copy = tmp_path / "a", tmp_path / "b"
    with StageRunner(original, {"seed": 0}) as runner:
        runner.run("pretrain", _weights_stage)
    stored = json.loads((original / "stages" / "pretrain.json").read_text())
    assert stored["result"]["path"] == "stages/pretrain/agent.pt"  # relative on disk
    assert str(tmp_path) not in (original / "stages" / "pretrain.json").read_text()
    shutil.copytree(original, copy)
    shutil.rmtree(original)
    with StageRunner(copy, {"seed": 0}) as runner:
        result = runner.run("pretrain", lambda d: pytest.fail("a finished stage reran"))
    assert result == {"path": str(copy / "stages" / "pretrain" / "agent.pt"),
                      "files": [str(copy / "stages" / "pretrain" / "agent.pt")],
                      "target": "foam"}
    assert os.path.exists(result["path"])


def test_a_relative_output_dir_resumes_from_another_working_directory(tmp_path, monkeypatch):
    (tmp_path / "home").mkdir()
    monkeypatch.chdir(tmp_path / "home")
    with StageRunner("runs/a", {"seed": 0}) as runner:
        runner.run("pretrain", _weights_stage)
    monkeypatch.chdir(tmp_path)
    result = read_stage_record("home/runs/a", "pretrain")["result"]
    assert result["path"] == os.path.join("home", "runs", "a", "stages", "pretrain", "agent.pt")
    assert os.path.exists(result["path"])


def test_a_hand_edited_stage_record_is_refused_naming_the_file(tmp_path):
    with StageRunner(tmp_path, {"seed": 0}) as runner:
        runner.run("zero_shot", lambda d: {"return": 412.0})
    record = tmp_path / "stages" / "zero_shot.json"
    stored = json.loads(record.read_text())
    stored["result"]["return"] = 950.0  # a better figure typed in
    record.write_text(json.dumps(stored))
    with StageRunner(tmp_path, {"seed": 0}) as runner, \
            pytest.raises(EditedRecordError, match=r"zero_shot\.json was changed after the run"):
        runner.run("zero_shot", lambda d: {"return": 0.0})
    assert issubclass(EditedRecordError, RunFolderError)  # recipes: exit 2, no traceback
    # a record written before seals existed is read as it is
    del stored[DIGEST_KEY]
    record.write_text(json.dumps(stored))
    with StageRunner(tmp_path, {"seed": 0}) as runner:
        assert runner.run("zero_shot", lambda d: {})["return"] == 950.0


def test_a_folder_with_finished_stages_but_no_config_is_refused(tmp_path):
    with StageRunner(tmp_path, {"episodes": 3}) as runner:
        runner.run("zero_shot", lambda d: {"return": 412.0})
    (tmp_path / "config.json").unlink()
    with pytest.raises(RunFolderError, match=r"finished stages \['zero_shot'\] but no "
                                             r"config.json"):
        StageRunner(tmp_path, {"episodes": 2})
    assert not (tmp_path / "config.json").exists()  # not rebuilt from the command line
    # an empty folder (or one with no finished stage) starts as before
    StageRunner(tmp_path / "fresh", {"episodes": 2}).close()


def test_results_json_is_relocatable_and_an_edit_is_refused_where_it_is_read(tmp_path):
    run = tmp_path / "run"
    (run / "stages").mkdir(parents=True)
    (run / "forward.png").write_bytes(b"png")
    write_run_json(run / "results.json", {"config": {"output_dir": str(run), "episodes": 3},
                                          "plot": str(run / "forward.png"), "mean": 0.5}, run)
    stored = json.loads((run / "results.json").read_text())
    assert stored["plot"] == "forward.png" and stored["config"]["output_dir"] == str(run)
    moved = tmp_path / "moved"
    run.rename(moved)
    assert read_run_json(moved / "results.json")["plot"] == str(moved / "forward.png")
    stored["mean"] = 0.9
    (moved / "results.json").write_text(json.dumps(stored))
    with pytest.raises(EditedRecordError, match="results.json was changed after the run"):
        read_run_json(moved / "results.json")

    # --config refuses an edited results.json too (exit 2 in the recipes)

    @dataclasses.dataclass
    class Cfg:
        output_dir: str = ""
        episodes: int = 8

    with pytest.raises(ConfigError, match="was changed after the run wrote it"):
        config_file(Cfg, moved / "results.json")
    (moved / "results.json").write_text(json.dumps(seal({**stored, "mean": 0.9})))
    assert config_file(Cfg, moved / "results.json")["episodes"] == 3
