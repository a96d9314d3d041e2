"""Data folders are data: a planted pickle never runs, a short or altered file is caught."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict

from simdist.data import DatasetConfig, generate_dataset, load_dataset
from simdist.experts import Expert
from simdist.pipelines.online_dreamer import load_episodes
from simdist.utils import CorruptDataError, load_memmap, save_memmap
from simdist.utils.memmap import MANIFEST


class _Payload:
    """Unpickling this writes a marker file: proof that pickled code ran."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (exec, (f"__import__('pathlib').Path({self.marker!r}).write_text('ran')",))


def _plant(folder: Path, marker: Path) -> None:
    """Adds a pickled non-tensor field to an existing memmap folder, as an attacker would
    (dropping the manifest that would otherwise report the folder as altered)."""
    evil = TensorDict({}, [])
    evil.set_non_tensor("payload", _Payload(marker))
    scratch = folder.parent / (folder.name + "_evil")
    evil.memmap(scratch)
    shutil.copytree(scratch / "payload", folder / "payload")
    meta = json.loads((folder / "meta.json").read_text())
    meta["payload"] = json.loads((scratch / "meta.json").read_text())["payload"]
    (folder / "meta.json").write_text(json.dumps(meta))
    shutil.rmtree(scratch)
    (folder / MANIFEST).unlink(missing_ok=True)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    cfg = DatasetConfig(episodes=2, shard_episodes=2, episode_steps=6)
    return cfg, generate_dataset(cfg, tmp_path_factory.mktemp("ds") / "ds",
                                 Expert.untrained(89, 12, hidden=8), progress=False)


def test_the_payload_would_run_through_tensordict_defaults(tmp_path):
    # Guards the test itself: the planted folder is a real exploit for a pickle-allowing load.
    folder, marker = tmp_path / "f", tmp_path / "ran"
    save_memmap(TensorDict({"x": torch.zeros(3)}, [3]), folder)
    _plant(folder, marker)
    TensorDict.load_memmap(folder, allow_pickle=True)
    assert marker.exists()


def test_episode_folder_with_pickle_is_refused(tmp_path):
    stage, marker = tmp_path / "stage", tmp_path / "ran"
    save_memmap(TensorDict({"x": torch.zeros(3)}, [3]), stage / "episodes" / "00000")
    _plant(stage / "episodes" / "00000", marker)
    with pytest.raises(CorruptDataError, match="00000"):
        load_episodes(stage)
    assert not marker.exists()


def test_dataset_with_pickle_is_refused_on_load_and_on_resume(dataset, tmp_path):
    cfg, path = dataset
    copy, marker = tmp_path / "ds", tmp_path / "ran"
    shutil.copytree(path, copy)
    _plant(copy / "data", marker)
    with pytest.raises(CorruptDataError):
        load_dataset(copy, slice_len=2, batch_size=4)
    meta = json.loads((copy / "meta.json").read_text())
    meta["shards_done"] = []  # looks unfinished: generate_dataset resumes it
    (copy / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(CorruptDataError, match="pickled"):
        generate_dataset(cfg, copy, Expert.untrained(89, 12, hidden=8), progress=False)
    assert not marker.exists()


def test_round_data_folder_with_pickle_is_refused(tmp_path):
    # The SimDist recipe's round data is written by save_memmap and read by load_memmap.
    folder, marker = tmp_path / "round_1" / "data", tmp_path / "ran"
    save_memmap(TensorDict({"observation": torch.zeros(4, 5)}, [4]), folder)
    _plant(folder, marker)
    with pytest.raises(CorruptDataError, match="pickled"):
        load_memmap(folder)
    assert not marker.exists()


def test_a_folder_changed_after_writing_fails_its_manifest(tmp_path):
    folder = tmp_path / "f"
    save_memmap(TensorDict({"x": torch.zeros(4)}, [4]), folder)
    manifest = (folder / MANIFEST).read_text()
    _plant(folder, tmp_path / "ran")
    (folder / MANIFEST).write_text(manifest)
    with pytest.raises(CorruptDataError, match="meta.json.*altered"):
        load_memmap(folder)


def test_truncated_leaf_is_caught_and_left_as_is(tmp_path):
    folder = tmp_path / "f"
    save_memmap(TensorDict({"x": torch.arange(80.0).reshape(80, 1)}, [80]), folder)
    leaf = folder / "x.memmap"
    leaf.write_bytes(leaf.read_bytes()[:29 * 4])
    with pytest.raises(CorruptDataError, match="x.memmap.*truncated"):
        load_memmap(folder)
    assert leaf.stat().st_size == 29 * 4  # not zero-extended on disk


def test_altered_bytes_fail_the_checksum(dataset, tmp_path):
    _, path = dataset
    copy = tmp_path / "ds"
    shutil.copytree(path, copy)
    leaf = next((copy / "data").rglob("*.memmap"))
    raw = bytearray(leaf.read_bytes())
    raw[0] ^= 0xFF
    leaf.write_bytes(bytes(raw))
    with pytest.raises(CorruptDataError, match="checksum"):
        load_dataset(copy, slice_len=2, batch_size=4)


def test_incomplete_dataset_names_a_command_that_finishes_it(dataset, tmp_path):
    cfg, path = dataset
    copy = tmp_path / "ds"
    shutil.copytree(path, copy)
    meta = json.loads((copy / "meta.json").read_text())
    meta["shards_done"] = []
    (copy / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(RuntimeError, match="generate_dataset"):
        load_dataset(copy, slice_len=2, batch_size=4)
    # the advice is true: the same config finishes it, and then it loads
    generate_dataset(cfg, copy, Expert.untrained(89, 12, hidden=8), progress=False)
    assert len(load_dataset(copy, slice_len=2, batch_size=4)) == 12


def test_corrupt_dataset_meta_names_the_file(dataset, tmp_path):
    _, path = dataset
    copy = tmp_path / "ds"
    shutil.copytree(path, copy)
    (copy / "meta.json").write_text("{not json")
    with pytest.raises(CorruptDataError, match="meta.json"):
        load_dataset(copy, slice_len=2, batch_size=4)


def test_save_memmap_refuses_non_tensor_fields(tmp_path):
    td = TensorDict({"x": torch.zeros(2)}, [2])
    td.set_non_tensor("note", "hello")
    with pytest.raises(TypeError, match="note"):
        save_memmap(td, tmp_path / "f")
    assert not (tmp_path / "f").exists()
