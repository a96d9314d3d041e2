"""SAC expert training: checkpoints are atomic, weights-only, resumable; snapshots kept."""

import pytest
import torch

from simdist.experts import Expert, SACExpertConfig, train_sac_expert
from simdist.experts.sac import make_training_env

TINY = dict(num_envs=2, init_random_frames=128, frames_per_batch=64, updates_per_batch=2,
            batch_size=32, checkpoint_every=256, snapshot_every=256, eval_episodes=1,
            episode_steps=40, hidden=32)


def test_tiny_training_run_resumes_and_exports(tmp_path):
    first = train_sac_expert(SACExpertConfig(total_frames=512, **TINY), tmp_path, progress=False)
    ckpt = torch.load(first, weights_only=True)  # no pickled code needed
    assert ckpt["frames"] == 512 and len(ckpt["curve"]) == 2
    assert list(ckpt["snapshots"]) == ["frames_256"]
    # resume: a larger budget continues from 512 frames instead of starting over
    second = train_sac_expert(SACExpertConfig(total_frames=768, **TINY), tmp_path, progress=False)
    ckpt = torch.load(second, weights_only=True)
    assert ckpt["frames"] == 768 and [c["frames"] for c in ckpt["curve"]] == [256, 512, 768]
    expert = Expert.load(second)
    td = make_training_env(SACExpertConfig(**TINY), seed=0, num_envs=3).reset()
    action = expert.act(td)["action"]
    assert action.shape == (3, 12) and (action.abs() <= 1).all()
    assert expert.value(td).shape == (3, 1)
    early = Expert.load(second, snapshot="frames_256")
    assert not torch.equal(early.act(td)["action"], action)
    with pytest.raises(KeyError, match="available: \\['frames_256'"):
        Expert.load(second, snapshot="frames_1")


def test_missing_checkpoint_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist; train it first"):
        Expert.load(tmp_path / "nope.pt")


def test_bad_config_is_rejected():
    with pytest.raises(ValueError, match="multiple of num_envs"):
        SACExpertConfig(num_envs=3, frames_per_batch=64)


def test_fast_deterministic_policy_matches_the_actor():
    torch.manual_seed(0)
    expert = Expert.untrained(obs_dim=89, action_dim=12, hidden=32)
    from tensordict import TensorDict
    td = TensorDict({"observation": torch.randn(5, 89) * 3}, [5])
    torch.testing.assert_close(expert.deterministic()(td.clone())["action"],
                               expert.act(td.clone())["action"])


def test_load_checks_the_experts_keys_and_weights(tmp_path):
    from simdist.utils import CorruptCheckpointError, load_checkpoint, save_atomic

    path = Expert.untrained(obs_dim=5, action_dim=2, hidden=8).save(
        tmp_path / "expert.pt", obs_dim=5, config=SACExpertConfig(hidden=8))
    assert Expert.load(path).act(
        __import__("tensordict").TensorDict({"observation": torch.zeros(1, 5)}, [1])
    )["action"].shape == (1, 2)
    good = load_checkpoint(path)
    for key in Expert.REQUIRED_KEYS:
        save_atomic({k: v for k, v in good.items() if k != key}, tmp_path / "bad.pt")
        with pytest.raises(CorruptCheckpointError, match=f"lacks \\['{key}'\\]") as info:
            Expert.load(tmp_path / "bad.pt")
        assert str(tmp_path / "bad.pt") in str(info.value) and "train_expert" in str(info.value)
    save_atomic({**good, "obs_dim": 7}, tmp_path / "bad.pt")  # weights of another size
    with pytest.raises(CorruptCheckpointError, match="weights do not fit"):
        Expert.load(tmp_path / "bad.pt")
    (tmp_path / "bad.pt").write_bytes(path.read_bytes()[:100])  # truncated
    with pytest.raises(CorruptCheckpointError, match="corrupt or incompatible.*train_expert"):
        Expert.load(tmp_path / "bad.pt")


def test_warm_start_puts_the_loaded_critic_into_every_q_copy(tmp_path):
    # SACLoss re-initialises its Q copies; a warm start must overwrite all of them (and
    # their targets) with the loaded critic, or the actor is trained on a random critic.
    start = train_sac_expert(SACExpertConfig(total_frames=256, **TINY), tmp_path / "a",
                             progress=False)
    loaded = Expert.load(start)
    cfg = SACExpertConfig(total_frames=64, init_from=str(start), alpha_init=0.02,
                          **{**TINY, "init_random_frames": 10_000, "checkpoint_every": 64})
    train_sac_expert(cfg, tmp_path / "b", progress=False)  # no update before it saves
    state = torch.load(tmp_path / "b" / "latest.pt", weights_only=True)["loss"]
    critic = loaded.critic.state_dict()
    for prefix in ("qvalue_network_params", "target_qvalue_network_params"):
        for name, value in critic.items():
            saved = state[f"{prefix}.{name}"]
            assert saved.shape[0] == 2
            torch.testing.assert_close(saved, value.expand_as(saved))
    actor = loaded.actor.state_dict()
    for name, value in actor.items():
        torch.testing.assert_close(state[f"actor_network_params.{name}"], value)
    assert abs(state["log_alpha"].exp().item() - 0.02) < 1e-6


@pytest.mark.parametrize("task, action_dim", [("block-push", 4), ("peg-insertion", 3)])
def test_a_manipulation_expert_trains_on_its_grid_and_reports_success(tmp_path, task,
                                                                      action_dim):
    from simdist.experts.sac import task_kwargs
    cfg = SACExpertConfig(task=task, init="wide", total_frames=256, **TINY)
    assert task_kwargs(cfg) == {"init": "wide"}
    path = train_sac_expert(cfg, tmp_path, progress=False)
    curve = torch.load(path, weights_only=True)["curve"]
    assert "success" in curve[-1] and 0 <= curve[-1]["success"] <= 1
    assert "forward_progress" not in curve[-1]  # locomotion's reading only
    env = make_training_env(cfg, seed=0, num_envs=2)
    assert env.sims[0].task.init == "wide"
    td = env.reset()
    assert Expert.load(path).act(td)["action"].shape == (2, action_dim)
