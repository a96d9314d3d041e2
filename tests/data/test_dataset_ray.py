"""The Ray backend: the same shards as the local one, and it resumes a local run.

Skipped where Ray is not installed (``pip install -e ".[distributed]"``).
"""

import json

import pytest
import torch

import simdist.data.dataset as dataset_module
from simdist.data import DatasetConfig, generate_dataset
from simdist.experts import Expert
from simdist.utils import load_memmap

ray = pytest.importorskip("ray")

CFG = DatasetConfig(episodes=6, shard_episodes=2, episode_steps=10)


@pytest.fixture(scope="module")
def cluster():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


@pytest.fixture(scope="module")
def experts():
    torch.manual_seed(0)
    return Expert.untrained(89, 12, hidden=16), [Expert.untrained(89, 12, hidden=16)]


def test_ray_shards_equal_local_shards(tmp_path, cluster, experts):
    local = generate_dataset(CFG, tmp_path / "local", *experts, progress=False)
    remote = generate_dataset(CFG, tmp_path / "ray", *experts, progress=False, backend="ray")
    a, b = load_memmap(local / "data"), load_memmap(remote / "data")
    assert a.shape == b.shape == (6, 10)
    assert (a == b).all()
    meta = json.loads((remote / "meta.json").read_text())
    assert meta["shards_done"] == [0, 1, 2] and meta["transitions"] == 60


def test_a_killed_local_run_resumes_on_ray(tmp_path, cluster, experts, monkeypatch):
    real = dataset_module._label_shard

    def crash_on_second(cfg, shard, *args, **kwargs):  # a kill between two shards
        if shard == 1:
            raise KeyboardInterrupt("killed mid-run")
        return real(cfg, shard, *args, **kwargs)

    monkeypatch.setattr(dataset_module, "_label_shard", crash_on_second)
    with pytest.raises(KeyboardInterrupt):
        generate_dataset(CFG, tmp_path / "run", *experts, progress=False)
    monkeypatch.setattr(dataset_module, "_label_shard", real)
    assert json.loads((tmp_path / "run" / "meta.json").read_text())["shards_done"] == [0]
    generate_dataset(CFG, tmp_path / "run", *experts, progress=False, backend="ray",
                     max_in_flight=1)
    reference = generate_dataset(CFG, tmp_path / "ref", *experts, progress=False)
    resumed = load_memmap(tmp_path / "run" / "data")
    assert (resumed == load_memmap(reference / "data")).all()
    assert sorted(resumed["episode"][:, 0].tolist()) == list(range(6))
