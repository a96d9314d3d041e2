import json
import os

import pytest
import torch

from simdist.utils import StageRunner, load_checkpoint, save_atomic


def test_finished_stages_are_skipped_and_killed_ones_rerun(tmp_path):
    calls = []

    def stage(directory):
        calls.append(directory.name)
        return {"value": len(calls)}

    runner = StageRunner(tmp_path, {"seed": 1})
    assert runner.run("a", stage) == {"value": 1}

    def killed(directory):
        (directory / "partial.txt").write_text("half done")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        runner.run("b", killed)
    rerun = StageRunner(tmp_path, {"seed": 1})
    assert rerun.run("a", stage) == {"value": 1} and calls == ["a"]  # not rerun
    assert rerun.run("b", stage) == {"value": 2}  # the killed stage runs again
    assert (tmp_path / "stages" / "b" / "partial.txt").exists()  # its checkpoint is kept
    assert set(rerun.timings) == {"a", "b"}


def test_a_different_config_is_refused(tmp_path):
    StageRunner(tmp_path, {"seed": 1, "steps": 5})
    with pytest.raises(ValueError, match="changed: \\['steps'\\]"):
        StageRunner(tmp_path, {"seed": 1, "steps": 6})


def test_atomic_save_keeps_the_old_file_when_writing_fails(tmp_path):
    path = tmp_path / "ckpt.pt"
    save_atomic({"w": torch.ones(2)}, path)

    class Unpicklable:
        def __reduce__(self):
            raise RuntimeError("boom")

    with pytest.raises(RuntimeError, match="boom"):
        save_atomic({"w": Unpicklable()}, path)
    assert torch.equal(load_checkpoint(path)["w"], torch.ones(2))
    assert [p.name for p in tmp_path.iterdir()] == ["ckpt.pt"]  # no temp files left


def test_checkpoints_never_run_pickled_code(tmp_path):
    path = tmp_path / "evil.pt"

    class Payload:
        def __reduce__(self):
            return (os.system, ("echo pwned",))

    torch.save({"x": Payload()}, path)
    with pytest.raises(Exception, match="[Ww]eights only"):
        load_checkpoint(path)
