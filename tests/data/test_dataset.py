"""On-disk perturbed-expert datasets: resumable without duplicates or losses; clean slices."""

import dataclasses
import json
import shutil

import pytest
import torch
import torchrl

import simdist.data.dataset as dataset_module
from simdist.data import (DatasetConfig, collect_shards, generate_dataset, generate_shard,
                          load_dataset)
from simdist.experts import Expert
from simdist.utils import RunFolderError, load_memmap

CFG = DatasetConfig(episodes=6, shard_episodes=2, episode_steps=12, dynamics_randomisation=True)


@pytest.fixture(scope="module")
def experts():
    torch.manual_seed(0)
    return Expert.untrained(89, 12, hidden=16), [Expert.untrained(89, 12, hidden=16)]


@pytest.fixture(scope="module")
def reference(tmp_path_factory, experts):
    return generate_dataset(CFG, tmp_path_factory.mktemp("ref"), *experts, progress=False)


def test_dataset_layout_and_metadata(reference, experts):
    data = load_memmap(reference / "data")
    assert data.shape == (6, 12)
    assert torch.equal(data["episode"][:, 0], torch.arange(6))
    assert data["is_init"][:, 0].all() and not data["is_init"][:, 1:].any()
    # each episode ends (truncated, not terminated) exactly at its last stored step
    for key in (("next", "truncated"), ("next", "done")):
        assert data[key][:, -1].all() and not data[key][:, :-1].any(), key
    assert not data["next", "terminated"].any() and not data["done"].any()
    meta = json.loads((reference / "meta.json").read_text())
    assert meta["shards_done"] == [0, 1, 2] and meta["transitions"] == 72
    assert meta["versions"]["torchrl"] == torchrl.__version__ and meta["bytes"] > 0
    for key in ("observation", "state", "action", ("next", "reward"), "value_target",
                "expert_active", "policy_index", "dynamics"):
        assert key in data.keys(True), key
    # both the final expert (0) and the snapshot (1) drove some episodes
    assert set(data["policy_index"][:, 0, 0].tolist()) <= {0, 1}


def test_value_labels_equal_the_critic_on_stored_observations(reference, experts):
    data = load_memmap(reference / "data").reshape(-1)
    expected = experts[0].value(data.select("observation").to_tensordict())
    torch.testing.assert_close(data["value_target"].clone(), expected)


def test_killed_generation_resumes_without_duplicates_or_losses(tmp_path, experts, reference,
                                                                  monkeypatch):
    real = dataset_module._label_shard
    calls = []

    def crash_on_third(cfg, shard, *args, **kwargs):  # a kill between two shards
        calls.append(shard)
        if shard == 2:
            raise KeyboardInterrupt("killed mid-run")
        return real(cfg, shard, *args, **kwargs)

    monkeypatch.setattr(dataset_module, "_label_shard", crash_on_third)
    with pytest.raises(KeyboardInterrupt):
        generate_dataset(CFG, tmp_path, *experts, progress=False)
    assert json.loads((tmp_path / "meta.json").read_text())["shards_done"] == [0, 1]
    with pytest.raises(RuntimeError, match="incomplete"):
        load_dataset(tmp_path, slice_len=4, batch_size=8)
    monkeypatch.setattr(dataset_module, "_label_shard", real)
    generate_dataset(CFG, tmp_path, *experts, progress=False)  # the same command again
    resumed = load_memmap(tmp_path / "data")
    ref = load_memmap(reference / "data")
    assert (resumed == ref).all()  # identical: no duplicated, no missing trajectory
    assert sorted(resumed["episode"][:, 0].tolist()) == list(range(6))


def test_resume_with_a_different_config_is_refused(reference, experts):
    with pytest.raises(RunFolderError, match="different config"):
        generate_dataset(DatasetConfig(episodes=6, shard_episodes=2, episode_steps=13),
                         reference, *experts, progress=False)


def test_a_powered_upright_term_lowers_only_the_rewards(tmp_path, reference, experts):
    """The same seed with ``upright_power=3``: the same trajectories (the reward does not
    steer the policy), every reward at most the plain one, and lower where the body tilts."""
    powered_cfg = dataclasses.replace(CFG, upright_power=3.0)
    powered = load_memmap(generate_dataset(powered_cfg, tmp_path, *experts, progress=False)
                          / "data")
    plain = load_memmap(reference / "data")
    assert torch.equal(powered["observation"], plain["observation"])
    assert torch.equal(powered["action"], plain["action"])
    r, r3 = plain["next", "reward"], powered["next", "reward"]
    assert (r3 <= r + 1e-6).all() and (r3 < r - 1e-6).any()


def test_a_dataset_from_before_upright_power_resumes_as_the_plain_reward(tmp_path, reference,
                                                                         experts):
    old = tmp_path / "old"
    shutil.copytree(reference, old)
    meta = json.loads((old / "meta.json").read_text())
    del meta["config"]["upright_power"]  # as written before the field existed
    (old / "meta.json").write_text(json.dumps(meta))
    generate_dataset(CFG, old, *experts, progress=False)  # the same command: nothing to do
    with pytest.raises(RunFolderError, match="different config"):
        generate_dataset(dataclasses.replace(CFG, upright_power=10.0), old, *experts,
                         progress=False)


def test_slices_never_cross_episode_boundaries(reference):
    buffer = load_dataset(reference, slice_len=5, batch_size=40)
    for _ in range(20):
        batch = buffer.sample().reshape(8, 5)
        episodes, steps = batch["episode"], batch["step"]
        assert (episodes == episodes[:, :1]).all()
        assert (steps[:, 1:] - steps[:, :-1] == 1).all()


def test_a_buffer_of_some_entries_samples_the_same_slices_of_those_entries(reference):
    keys = ["observation", ("next", "reward")]
    torch.manual_seed(1)
    full = [load_dataset(reference, slice_len=4, batch_size=8).sample() for _ in range(5)]
    torch.manual_seed(1)
    some = [load_dataset(reference, slice_len=4, batch_size=8, keys=keys).sample()
            for _ in range(5)]
    assert "state" not in some[0].keys() and "episode" in some[0].keys()
    for a, b in zip(full, some):
        assert (a.select(*keys, "episode") == b.select(*keys, "episode")).all()


def test_bad_dataset_config():
    with pytest.raises(ValueError, match="multiple of shard_episodes"):
        DatasetConfig(episodes=5, shard_episodes=2)


def test_worker_processes_give_a_deterministic_resumable_dataset(tmp_path, experts):
    cfg = DatasetConfig(episodes=4, shard_episodes=4, num_workers=2, episode_steps=8)
    a = generate_dataset(cfg, tmp_path / "a", *experts, progress=False)
    b = generate_dataset(cfg, tmp_path / "b", *experts, progress=False)
    da, db = load_memmap(a / "data"), load_memmap(b / "data")
    assert da.shape == (4, 8) and (da == db).all()
    assert torch.equal(da["episode"][:, 0], torch.arange(4))
    with pytest.raises(ValueError, match="multiple of num_workers"):
        DatasetConfig(episodes=6, shard_episodes=3, num_workers=2)
    with pytest.raises(ValueError, match=r"use \[1, 2, 4, 8, 16, 32\] workers"):
        DatasetConfig(episodes=64, shard_episodes=32, num_workers=12)


def test_shards_made_side_by_side_equal_one_collector_and_resume(tmp_path, experts,
                                                                  reference, monkeypatch):
    # Two one-thread worker processes (this process may have more threads): the same bytes.
    side = generate_dataset(CFG, tmp_path / "side", *experts, progress=False, jobs=2,
                            threads=1)
    assert (load_memmap(side / "data") == load_memmap(reference / "data")).all()
    meta = json.loads((side / "meta.json").read_text())
    assert meta["shards_done"] == [0, 1, 2] and meta["transitions"] == 72
    # A run stopped after one shard resumes side by side with the rest only.
    real = dataset_module._shards_side_by_side

    def first_only(cfg, todo, *args):
        for shard, rows in real(cfg, todo, *args):
            yield shard, rows
            raise KeyboardInterrupt("killed after one shard")

    monkeypatch.setattr(dataset_module, "_shards_side_by_side", first_only)
    with pytest.raises(KeyboardInterrupt):
        generate_dataset(CFG, tmp_path / "run", *experts, progress=False, jobs=2, threads=1)
    assert len(json.loads((tmp_path / "run" / "meta.json").read_text())["shards_done"]) == 1
    monkeypatch.setattr(dataset_module, "_shards_side_by_side", real)
    resumed = generate_dataset(CFG, tmp_path / "run", *experts, progress=False, jobs=2,
                               threads=1)
    assert (load_memmap(resumed / "data") == load_memmap(reference / "data")).all()


def test_unknown_backend_is_refused(tmp_path, experts):
    with pytest.raises(ValueError, match="unknown backend"):
        generate_dataset(CFG, tmp_path, *experts, progress=False, backend="dask")


def test_one_collector_over_several_shards_equals_one_shard_at_a_time(experts):
    # The collector's pre-collect hook reseeds env and policy per batch: shards taken in
    # any order from one long-lived collector equal shards made each by a fresh one.
    together = dict(collect_shards(CFG, [2, 0], *experts))
    assert set(together) == {2, 0}
    for shard, rows in together.items():
        alone = generate_shard(CFG, shard, *experts)
        assert (rows == alone).all()
        assert torch.equal(rows["episode"][:, 0], torch.arange(2) + 2 * shard)


def test_whole_dataset_is_a_view_of_the_memory_map(reference):
    # recipes read the whole dataset (normalisation statistics, sizes) through buffer[:],
    # TorchRL's public indexing, instead of buffer.storage._storage: the same tensors,
    # no copy of what may be hundreds of MB
    buffer = load_dataset(reference, slice_len=4, batch_size=8)
    whole, stored = buffer[:], buffer.storage._storage
    assert whole.batch_size == stored.batch_size
    for key in ("observation", "action", "state"):
        assert torch.equal(whole[key], stored[key]), key
        assert whole[key].untyped_storage().data_ptr() == stored[key].untyped_storage().data_ptr()
