"""Asymmetric SAC: the actor reads pixels only, the critic the privileged state only."""

import pytest
import torch
from tensordict import TensorDict

from simdist.agents import AsymmetricSACAgent, AsymmetricSACConfig
from simdist.agents.asymmetric_sac import transitions_from_slices


def _slices(B=4, T=3, state_dim=5, action_dim=1):
    torch.manual_seed(0)
    return TensorDict({"action": torch.rand(B, T, action_dim) * 2 - 1,
                       "is_init": torch.zeros(B, T, 1, dtype=torch.bool),
                       "next": {"state": torch.randn(B, T, state_dim),
                                "pixels": torch.randint(0, 255, (B, T, 64, 64, 3),
                                                        dtype=torch.uint8),
                                "reward": torch.ones(B, T, 1),
                                "terminated": torch.zeros(B, T, 1, dtype=torch.bool)}}, [B, T])


def test_transitions_pair_each_step_with_the_previous_next_and_drop_episode_starts():
    batch = _slices(B=2, T=4)
    batch["is_init"][1, 2] = True  # an episode starts inside slice 1 at step 2
    t = transitions_from_slices(batch)
    assert t.shape == (2 * 3 - 1,)
    torch.testing.assert_close(t["pixels"][0], batch["next", "pixels"][0, 0])
    torch.testing.assert_close(t["next", "pixels"][0], batch["next", "pixels"][0, 1])
    torch.testing.assert_close(t["action"][0], batch["action"][0, 1])
    # slice 1 keeps steps 1 and 3, not the episode start at step 2
    torch.testing.assert_close(t["action"][3:], batch["action"][1, [1, 3]])
    with pytest.raises(ValueError, match="slices"):
        transitions_from_slices(batch[:, :1])


def test_critic_reads_the_state_and_actor_the_pixels_and_both_learn():
    agent = AsymmetricSACAgent(5, 1, AsymmetricSACConfig(depth=4, hidden=16))
    loss = agent.loss
    assert loss.actor_network.in_keys == ["pixels"]
    assert set(loss.qvalue_network.in_keys) == {"state", "action"}
    # no LayerNorm on the few state features (it erases each sample's mean and scale)
    assert not any(isinstance(m, torch.nn.LayerNorm) for m in loss.qvalue_network.modules())
    with_norm = AsymmetricSACAgent(5, 1, AsymmetricSACConfig(depth=4, hidden=16,
                                                             critic_layer_norm=True))
    assert any(isinstance(m, torch.nn.LayerNorm)
               for m in with_norm.loss.qvalue_network.modules())
    actor_before = loss.actor_network_params.clone()
    q_before = loss.qvalue_network_params.clone()
    for _ in range(3):
        metrics = agent.update(_slices())
    assert {"loss_actor", "loss_qvalue", "loss_alpha"} <= set(metrics)
    moved = lambda a, b: any((x != y).any() for x, y in  # noqa: E731
                             zip(a.values(True, True), b.values(True, True)))
    assert moved(actor_before, loss.actor_network_params)
    assert moved(q_before, loss.qvalue_network_params)
    # the critic's input never involves an image: changing the pixels leaves Q unchanged
    data = transitions_from_slices(_slices())
    other = data.clone()
    other["pixels"] = torch.zeros_like(other["pixels"])
    with loss.qvalue_network_params[0].to_module(loss.qvalue_network):
        q1 = loss.qvalue_network(data.clone())["state_action_value"]
        q2 = loss.qvalue_network(other)["state_action_value"]
    torch.testing.assert_close(q1, q2)


def test_policy_acts_from_pixels_deterministically_when_not_exploring():
    agent = AsymmetricSACAgent(5, 2, AsymmetricSACConfig(depth=4, hidden=16))
    td = TensorDict({"pixels": torch.randint(0, 255, (3, 64, 64, 3), dtype=torch.uint8)}, [3])
    a1 = agent.policy(explore=False)(td.clone())["action"]
    a2 = agent.policy(explore=False)(td.clone())["action"]
    torch.testing.assert_close(a1, a2)
    assert a1.shape == (3, 2) and a1.abs().max() <= 1
    sampled = agent.policy(explore=True)(td.clone())["action"]
    assert not torch.equal(sampled, a1)
    # a state saved mid-training restores the same policy
    agent.update(_slices(action_dim=2))
    copy = AsymmetricSACAgent(5, 2, AsymmetricSACConfig(depth=4, hidden=16))
    copy.load_state_dict(agent.state_dict())
    torch.testing.assert_close(copy.policy(explore=False)(td.clone())["action"],
                               agent.policy(explore=False)(td.clone())["action"])


def test_saved_file_rebuilds_the_same_policy_and_refuses_other_classes(tmp_path):
    from simdist.agents import DreamerAgent, load_agent
    from simdist.utils.checkpoint import CorruptCheckpointError

    agent = AsymmetricSACAgent(5, 2, AsymmetricSACConfig(depth=4, hidden=16, shift_pad=2))
    agent.update(_slices(action_dim=2))  # trained weights, not the initial ones
    path = agent.save(tmp_path / "sac.pt", meta={"task": "cartpole-balance"})
    loaded = load_agent(path)
    assert type(loaded) is AsymmetricSACAgent and loaded.config.shift_pad == 2
    assert loaded.checkpoint_meta == {"task": "cartpole-balance"}
    td = TensorDict({"pixels": torch.randint(0, 255, (3, 64, 64, 3), dtype=torch.uint8)}, [3])
    torch.testing.assert_close(loaded.policy(explore=False)(td.clone())["action"],
                               agent.policy(explore=False)(td.clone())["action"])
    for a, b in zip(loaded.optim.state_dict()["state"].values(),
                    agent.optim.state_dict()["state"].values()):
        torch.testing.assert_close(a["exp_avg"], b["exp_avg"])
    with pytest.raises(CorruptCheckpointError, match="not a DreamerAgent"):
        DreamerAgent.load(path)
    bare = agent.save(tmp_path / "bare.pt", optimisers=False)
    assert "optimisers" not in torch.load(bare, weights_only=True)
    state = torch.load(path, weights_only=True)  # a file whose sizes do not fit its weights
    state["config"]["state_dim"] = 7
    torch.save(state, tmp_path / "bad.pt")
    with pytest.raises(CorruptCheckpointError, match="do not fit"):
        load_agent(tmp_path / "bad.pt")


def test_stacked_transitions_hold_the_last_frames_oldest_first_and_stay_in_one_episode():
    batch = _slices(B=2, T=5)
    batch["is_init"][1, 3] = True  # slice 1: an episode starts at step 3
    t = transitions_from_slices(batch, frames=3)
    # slice 0 acts at steps 3 and 4; slice 1's stacks would reach back across step 3
    assert t.shape == (2,) and t["pixels"].shape == (2, 3, 64, 64, 3)
    nxt = batch["next", "pixels"][0]
    torch.testing.assert_close(t["pixels"][0], nxt[0:3])
    torch.testing.assert_close(t["next", "pixels"][0], nxt[1:4])
    torch.testing.assert_close(t["pixels"][1], nxt[1:4])
    torch.testing.assert_close(t["action"], batch["action"][0, 3:5])
    torch.testing.assert_close(t["state"], batch["next", "state"][0, 2:4])
    torch.testing.assert_close(t["next", "state"], batch["next", "state"][0, 3:5])
    torch.testing.assert_close(t["next", "reward"], batch["next", "reward"][0, 3:5])
    with pytest.raises(ValueError, match="4"):
        transitions_from_slices(batch[:, :3], frames=3)
    with pytest.raises(ValueError, match="frames"):
        AsymmetricSACConfig(frames=0)


def _ramp(T=6):
    """One slice whose step i has reward i + 1 and state 10 + i."""
    batch = _slices(B=1, T=T, state_dim=1)
    batch["next", "reward"] = torch.arange(1.0, T + 1).reshape(1, T, 1)
    batch["next", "state"] = torch.arange(10.0, 10 + T).reshape(1, T, 1)
    return batch


@pytest.mark.parametrize("terminates", [False, True])
def test_n_step_returns_sum_discounted_rewards_and_stop_at_an_episode_end(terminates):
    g = 0.5
    t = transitions_from_slices(_ramp(), n_step=3, gamma=g)
    # no episode end: acting at steps 1, 2, 3, each sums three rewards, bootstraps 3 on
    assert t.shape == (3,)
    torch.testing.assert_close(t["next", "reward"].flatten(),
                               torch.tensor([2 + 3 * g + 4 * g ** 2, 3 + 4 * g + 5 * g ** 2,
                                             4 + 5 * g + 6 * g ** 2]))
    torch.testing.assert_close(t["next", "state"].flatten(), torch.tensor([13.0, 14.0, 15.0]))
    torch.testing.assert_close(t["steps_to_next_obs"].flatten(), torch.tensor([3.0, 3.0, 3.0]))
    assert not t["next", "terminated"].any()
    # an episode ends at step 2 (terminal, or cut by the time limit) and the next starts
    # at step 3: acting at step 1 sums steps 1-2, at step 2 step 2 alone; step 3 starts
    # the new episode and has no previous observation in this slice: dropped
    batch = _ramp()
    batch["is_init"][0, 3] = True
    batch["next", "terminated"][0, 2] = terminates
    t = transitions_from_slices(batch, n_step=3, gamma=g)
    assert t.shape == (2,)
    torch.testing.assert_close(t["next", "reward"].flatten(), torch.tensor([2 + 3 * g, 3.0]))
    torch.testing.assert_close(t["next", "state"].flatten(), torch.tensor([12.0, 12.0]))
    torch.testing.assert_close(t["steps_to_next_obs"].flatten(), torch.tensor([2.0, 1.0]))
    assert t["next", "terminated"].flatten().tolist() == [terminates, terminates]
    with pytest.raises(ValueError, match="4"):
        transitions_from_slices(batch[:, :3], n_step=3)
    with pytest.raises(ValueError, match="n_step"):
        AsymmetricSACConfig(n_step=0)
    with pytest.raises(ValueError, match="tau"):
        AsymmetricSACConfig(tau=0.0)


def test_n_step_target_bootstraps_with_gamma_to_the_power_of_the_steps_taken():
    # TorchRL's TD(0) estimator reads "steps_to_next_obs": target = R + gamma^m V(o_{t+m})
    agent = AsymmetricSACAgent(1, 1, AsymmetricSACConfig(depth=4, hidden=16, n_step=3))
    estimator = agent.loss.value_estimator
    td = TensorDict({"steps_to_next_obs": torch.tensor([[3.0], [1.0]]),
                     "next": {"reward": torch.tensor([[1.0], [1.0]]),
                              "state_value": torch.tensor([[10.0], [10.0]]),
                              "done": torch.zeros(2, 1, dtype=torch.bool),
                              "terminated": torch.zeros(2, 1, dtype=torch.bool)}}, [2])
    target = estimator.value_estimate(td).flatten()
    torch.testing.assert_close(target, torch.tensor([1 + 0.99 ** 3 * 10, 1 + 0.99 * 10]))
    # and a 3-step agent trains on slices of frames + 3 steps
    agent.update(_slices(T=4, state_dim=1))


def test_stacked_actor_reads_motion_carries_its_history_and_restarts_it_each_episode():
    from simdist.pipelines import control_env

    agent = AsymmetricSACAgent(5, 1, AsymmetricSACConfig(depth=4, hidden=16, frames=3))
    agent.update(_slices(T=4))
    policy = agent.policy(explore=False)
    assert agent.policy(explore=False).in_keys == ["pixels", "is_init", ("agent", "frames")]
    frames = torch.randint(0, 255, (4, 64, 64, 3), dtype=torch.uint8)
    td = TensorDict({"pixels": frames[2], "is_init": torch.ones(1, dtype=torch.bool),
                     "agent": {"frames": frames[:2]}}, [])
    out = policy(td.clone())
    # at an episode's start the stale history is replaced by the current image
    torch.testing.assert_close(out["next", "agent", "frames"], frames[2].expand(2, 64, 64, 3))
    td["is_init"][:] = False
    out = policy(td.clone())
    torch.testing.assert_close(out["next", "agent", "frames"], frames[1:3])
    # the action is the actor's on the stack, oldest first
    with agent.loss.actor_network_params.to_module(agent.loss.actor_network):
        from torchrl.envs.utils import ExplorationType, set_exploration_type
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            direct = agent.loss.actor_network(TensorDict({"pixels": frames[:3]}, []))["action"]
    torch.testing.assert_close(out["action"], direct)
    # a real env with the primer: the history rolls through an episode
    env = control_env("cartpole-balance", 0, pixels=True, max_episode_steps=4,
                      primer=agent.make_primer())
    rollout = env.rollout(4, policy)
    history, pixels = rollout["next", "agent", "frames"], rollout["pixels"]
    torch.testing.assert_close(history[0], pixels[0].expand(2, 64, 64, 3))
    torch.testing.assert_close(history[1], pixels[:2])
    torch.testing.assert_close(history[2], pixels[1:3])
    torch.testing.assert_close(rollout["agent", "frames"][1:], history[:-1])  # carried
    env.close()
    assert AsymmetricSACAgent(5, 1, AsymmetricSACConfig(depth=4, hidden=16)).make_primer() is None
