"""Online Dreamer loop: stores D, checkpoints, resumes without duplicating episodes."""

import pytest
import torch

from tensordict import TensorDict

from simdist.agents import DreamerAgent, DreamerConfig
from simdist.pipelines import (EpisodeReplay, OnlineConfig, control_env, dreamer_keys,
                               load_episodes, snapshot_paths, train_dreamer_online)
from simdist.utils import load_checkpoint


def _setup(pixels=False):
    torch.manual_seed(0)
    agent = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny", horizon=2))
    env = control_env("cartpole-balance", 0, pixels=pixels, max_episode_steps=12,
                      primer=agent.make_primer())
    config = OnlineConfig(env_steps=36, prefill_steps=12, train_every=6, episode_steps=12,
                          slice_len=6, slices=2)
    return agent, env, config


def test_run_collects_whole_episodes_and_records_pixels_with_state(tmp_path):
    agent, env, config = _setup(pixels=True)
    out = train_dreamer_online(agent, env, config, tmp_path, dreamer_keys("state", "pixels"),
                               progress=False)
    episodes = load_episodes(tmp_path)
    assert len(episodes) == 3 and out["updates"] == 3 * 2 and len(out["episode_returns"]) == 3
    for episode in episodes:
        assert episode.shape == (12,) and episode["is_init"][0].item()
        assert episode["next", "pixels"].shape == (12, 64, 64, 3)
        assert episode["next", "pixels"].dtype == torch.uint8
        assert episode["next", "state"].shape == (12, 5)
    assert "agent" not in episodes[0].keys()  # only the asked-for keys are stored


def test_snapshots_keep_the_agent_after_each_of_the_last_episodes(tmp_path):
    agent, env, config = _setup()
    assert snapshot_paths(tmp_path) == []
    with pytest.raises(ValueError, match="snapshots must be >= 0"):
        train_dreamer_online(agent, env, config, tmp_path, dreamer_keys("state"),
                             progress=False, snapshots=-1)
    train_dreamer_online(agent, env, config, tmp_path, dreamer_keys("state"), progress=False,
                         snapshots=2)
    paths = snapshot_paths(tmp_path)
    assert [p.name for p in paths] == ["00001.pt", "00002.pt"]  # of episodes 0, 1, 2
    first, last = (load_checkpoint(p)["weights"]["actor"] for p in paths)
    final = load_checkpoint(tmp_path / "training.pt")["agent"]["actor"]
    assert all(torch.equal(last[k], final[k]) for k in final)  # the last is the final agent
    assert not all(torch.equal(first[k], final[k]) for k in final)  # the one before is not


def test_killed_run_resumes_without_recollecting(tmp_path, monkeypatch):
    agent, env, config = _setup()
    import simdist.pipelines.online_dreamer as online

    calls = {"n": 0}
    original = online.save_atomic

    def crash_after_second_checkpoint(obj, path):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt  # killed after episode 2 was stored, before its checkpoint
        original(obj, path)

    monkeypatch.setattr(online, "save_atomic", crash_after_second_checkpoint)
    with pytest.raises(KeyboardInterrupt):
        train_dreamer_online(agent, env, config, tmp_path, dreamer_keys("state"),
                             progress=False)
    first_two = [e["next", "state"].clone() for e in load_episodes(tmp_path)]
    assert len(first_two) == 2
    monkeypatch.setattr(online, "save_atomic", original)
    agent, env, _ = _setup()
    out = train_dreamer_online(agent, env, config, tmp_path, dreamer_keys("state"),
                               progress=False)
    episodes = load_episodes(tmp_path)
    assert len(episodes) == 3 and out["updates"] == 6 and len(out["episode_returns"]) == 3
    for before, after in zip(first_two, episodes):
        assert torch.equal(before, after["next", "state"])  # stored episodes reused as is


def test_replay_slices_never_cross_episodes_and_bad_input_is_refused():
    replay = EpisodeReplay(capacity=64, slice_len=5, slices=16)
    for i in range(3):
        replay.add(TensorDict({"x": torch.full((8, 1), float(i))}, [8]))
    batch = replay.sample()
    assert batch.shape == (16, 5)
    assert (batch["x"] == batch["x"][:, :1]).all()
    with pytest.raises(ValueError, match="shorter than a slice"):
        replay.add(TensorDict({"x": torch.zeros(3, 1)}, [3]))
    with pytest.raises(ValueError, match="one episode"):
        replay.add(TensorDict({"x": torch.zeros(2, 8, 1)}, [2, 8]))


def test_bad_budgets_are_refused():
    with pytest.raises(ValueError, match="prefill_steps"):
        OnlineConfig(env_steps=10, prefill_steps=20)
    with pytest.raises(ValueError, match="slice_len"):
        OnlineConfig(episode_steps=10, slice_len=20)


@pytest.mark.parametrize("crash_at", [2, 3])  # after episode 2 was stored / before episode 3
def test_a_seeded_run_resumed_after_a_crash_equals_the_uninterrupted_run(tmp_path, monkeypatch,
                                                                          crash_at):
    import simdist.pipelines.online_dreamer as online

    agent, env, config = _setup()
    full = train_dreamer_online(agent, env, config, tmp_path / "full", dreamer_keys("state"),
                                progress=False, seed=7)
    full_weights = _flat(agent.state_dict())

    agent, env, _ = _setup()
    calls, original = {"n": 0}, online.save_atomic

    def crash(obj, path):
        calls["n"] += 1
        if calls["n"] == crash_at:
            raise KeyboardInterrupt
        original(obj, path)

    monkeypatch.setattr(online, "save_atomic", crash)
    with pytest.raises(KeyboardInterrupt):
        train_dreamer_online(agent, env, config, tmp_path / "resumed", dreamer_keys("state"),
                             progress=False, seed=7)
    monkeypatch.setattr(online, "save_atomic", original)
    torch.rand(1000)  # whatever else the process drew meanwhile must not matter
    agent, env, _ = _setup()
    env.set_seed(123)  # nor where the new process's env started
    resumed = train_dreamer_online(agent, env, config, tmp_path / "resumed",
                                   dreamer_keys("state"), progress=False, seed=7)
    assert resumed["episode_returns"] == full["episode_returns"]
    assert resumed["history"] == full["history"]
    resumed_weights = _flat(agent.state_dict())
    assert resumed_weights.keys() == full_weights.keys()
    for key, value in resumed_weights.items():
        assert torch.equal(value, full_weights[key]) if torch.is_tensor(value) \
            else value == full_weights[key], key


def _flat(state, prefix=""):
    """Every leaf of a nested state dict (weights and optimiser states), copied."""
    out = {}
    for key, value in state.items():
        if isinstance(value, dict):
            out.update(_flat(value, f"{prefix}{key}."))
        elif isinstance(value, (list, tuple)) and value and isinstance(value[0], dict):
            for i, item in enumerate(value):
                out.update(_flat(item, f"{prefix}{key}.{i}."))
        else:
            out[prefix + str(key)] = value.clone() if torch.is_tensor(value) else value
    return out
