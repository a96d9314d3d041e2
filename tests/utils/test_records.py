"""A run's records: config and stage JSONs of the run and of each seed folder, nothing else."""

import json
from pathlib import Path

import pytest

from simdist.utils.records import copy_records, main, record_files


def _write(path: Path, data) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data))


def _multi_seed_run(root: Path) -> Path:
    # the SimDist recipe's --seeds layout: an aggregate results.json over seed_<n>/ folders
    _write(root / "results.json", {"seeds": [0, 1]})
    for seed in (0, 1):
        folder = root / f"seed_{seed}"
        _write(folder / "config.json", {"seed": seed})
        _write(folder / "results.json", {"seed": seed})
        for stage in ("pretrain", "round_1"):
            _write(folder / "stages" / f"{stage}.json", {"result": {"seed": seed}})
        (folder / "stages" / "pretrain").mkdir()
        (folder / "stages" / "pretrain" / "world_model.pt").write_bytes(b"weights")
        _write(folder / "stages" / "dataset" / "meta.json", {"inside a stage folder": True})
    (root / "forward_progress.png").write_bytes(b"a plot, rebuilt from the records")
    return root


def test_records_are_config_results_and_stage_jsons_of_each_seed(tmp_path):
    run = _multi_seed_run(tmp_path / "run")
    expected = ["results.json"] + [f"seed_{s}/{f}" for s in (0, 1) for f in
                                   ("config.json", "results.json", "stages/pretrain.json",
                                    "stages/round_1.json")]
    assert [str(p) for p in record_files(run)] == expected
    copied = copy_records(run, tmp_path / "kept")
    assert sorted(str(p.relative_to(tmp_path / "kept")) for p in copied) == sorted(expected)
    for relative in expected:
        assert (tmp_path / "kept" / relative).read_bytes() == (run / relative).read_bytes()
    assert not list((tmp_path / "kept").rglob("*.pt"))
    assert not (tmp_path / "kept" / "seed_0" / "stages" / "dataset").exists()
    assert copy_records(run, tmp_path / "kept") == copied  # the same records again: no-op


def test_a_different_record_is_never_overwritten(tmp_path):
    run = _multi_seed_run(tmp_path / "run")
    copy_records(run, tmp_path / "kept")
    _write(run / "seed_1" / "stages" / "round_1.json", {"result": "another run's"})
    with pytest.raises(FileExistsError, match="seed_1/stages/round_1.json.*different record"):
        copy_records(run, tmp_path / "kept")
    kept = json.loads((tmp_path / "kept" / "seed_1" / "stages" / "round_1.json").read_text())
    assert kept == {"result": {"seed": 1}}


def test_a_folder_that_is_not_a_run_is_a_clear_error(tmp_path, capsys):
    (tmp_path / "stages").mkdir()
    with pytest.raises(FileNotFoundError, match="not a recipe's output folder"):
        record_files(tmp_path)
    with pytest.raises(SystemExit) as info:
        main([str(tmp_path), str(tmp_path / "kept")])
    assert info.value.code == 2
    assert "error: " in capsys.readouterr().err
    main([str(_multi_seed_run(tmp_path / "run")), str(tmp_path / "kept")])
    assert "copied 9 record files" in capsys.readouterr().out
