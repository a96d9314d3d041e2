"""Corrupt or incompatible files fail naming the file and how to recover (issue 18, item 4)."""

import os

import pytest
import torch

from simdist.utils import (CorruptCheckpointError, CorruptFileError, StageRunner,
                           load_checkpoint, save_atomic)


class _Payload:
    def __reduce__(self):
        return (os.system, ("echo pwned",))


def _corruptions(good: bytes) -> dict:
    return {"truncated": good[: len(good) // 2], "empty": b"", "text": b"hello world",
            "zeros": bytes(len(good)), "garbage": bytes(range(256)) * 4}


@pytest.mark.parametrize("kind", ["truncated", "empty", "text", "zeros", "garbage", "pickle"])
def test_corrupt_checkpoint_names_the_file_and_never_advises_unsafe_loading(tmp_path, kind):
    path = tmp_path / "stages" / "pretrain" / "world_model.pt"
    save_atomic({"w": torch.ones(50)}, path)
    if kind == "pickle":
        torch.save({"x": _Payload()}, path)
    else:
        path.write_bytes(_corruptions(path.read_bytes())[kind])
    with pytest.raises(CorruptCheckpointError) as info:
        load_checkpoint(path)
    message = str(info.value)
    assert str(path) in message and "corrupt or incompatible" in message
    # The recovery names the stage's record, so that a rerun redoes the stage.
    assert str(tmp_path / "stages" / "pretrain.json") in message
    assert "weights_only=False" not in message and "weights_only` set to `False" not in message
    assert info.value.__suppress_context__  # torch's advice is not shown underneath either
    if kind == "pickle":
        assert "posix.system" in message


def test_checkpoint_outside_stages_says_to_replace_it(tmp_path):
    path = tmp_path / "expert.pt"
    path.write_bytes(b"\x00" * 10)
    with pytest.raises(CorruptCheckpointError, match="delete or replace"):
        load_checkpoint(path)
    with pytest.raises(CorruptCheckpointError, match="retrain it"):
        load_checkpoint(path, recovery="retrain it")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_checkpoint(tmp_path / "missing.pt")


def test_corrupt_stage_record_names_it_and_says_to_delete_it(tmp_path):
    runner = StageRunner(tmp_path, {"seed": 0})
    runner.run("teacher", lambda d: {"return": 5})
    record = tmp_path / "stages" / "teacher.json"
    record.write_text(record.read_text()[:10])  # a crash or a full disk
    with pytest.raises(CorruptFileError, match="not valid JSON") as info:
        runner.run("teacher", lambda d: {"return": 6})
    assert str(record) in str(info.value) and f"delete {record}" in str(info.value)
    record.write_text('{"something": "else"}')
    with pytest.raises(CorruptFileError, match="incompatible"):
        runner.result("teacher")
    record.unlink()  # the advice works: the stage runs again
    assert runner.run("teacher", lambda d: {"return": 6}) == {"return": 6}
    runner.close()


@pytest.mark.parametrize("content", [b'{"seed": ', b"\xff\xfe\x00", b"[1, 2]"])
def test_corrupt_config_json_names_it_and_says_what_to_do(tmp_path, content):
    StageRunner(tmp_path, {"seed": 0}).close()
    config = tmp_path / "config.json"
    config.write_bytes(content)
    with pytest.raises(CorruptFileError) as info:
        StageRunner(tmp_path, {"seed": 0})
    assert str(config) in str(info.value) and "delete" in str(info.value)
    config.unlink()
    StageRunner(tmp_path, {"seed": 0}).close()  # and it is rewritten
    assert config.exists()
