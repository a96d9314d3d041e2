"""SimDist agent: a planning policy with its history in the TensorDict; finetuning scope."""

import copy

import torch
from torchrl.envs import InitTracker, TransformedEnv

from simdist.agents import SimDistAgent, SimDistConfig
from simdist.envs import make_env
from simdist.modules import SimDistWorldModel
from simdist.modules.planner import PlannerConfig
from tests.synthetic import linear_system_batch


def _agent(obs_dim=89, action_dim=12, lr=2e-4):
    torch.manual_seed(0)
    return SimDistAgent(SimDistWorldModel.build(obs_dim, action_dim, size="tiny", history=3),
                        SimDistConfig(horizon=3, lr=lr))


def test_planning_policy_runs_in_env_with_history_reset_per_episode():
    agent = _agent()
    env = TransformedEnv(make_env("quadruped-flat", seed=0, max_episode_steps=5, num_envs=2),
                         InitTracker())
    env.append_transform(agent.make_primer())
    spec = env.action_spec
    policy = agent.policy(spec.space.low[0], spec.space.high[0],
                          PlannerConfig(horizon=3, num_samples=16, num_elites=4, iterations=2))
    td = env.rollout(8, policy, break_when_any_done=False)
    low, high = spec.space.low[0], spec.space.high[0]
    assert ((td["action"] >= low) & (td["action"] <= high)).all()
    history = td["next", "simdist", "history"]                 # [2, 8, k, obs]
    obs = td["observation"]
    # newest entry is the current observation; at an episode start the window repeats it
    torch.testing.assert_close(history[..., -1, :], obs)
    starts = td["is_init"][..., 0]
    assert starts[:, 5].all()
    torch.testing.assert_close(history[:, 5], obs[:, 5, None].expand_as(history[:, 5]))
    torch.testing.assert_close(history[:, 6, :-1], history[:, 5, 1:])  # shifts by one


def test_finetune_update_moves_only_dynamics_and_whole_ablation_moves_encoder():
    agent = _agent(obs_dim=4, action_dim=2)
    batch = linear_system_batch(batch=8, time=8, obs_dim=4)
    before = copy.deepcopy(agent.world_model.state_dict())
    for _ in range(3):
        agent.finetune_update(batch.clone())
    changed = {k.split(".")[0] for k, v in agent.world_model.state_dict().items()
               if not torch.equal(v, before[k])}
    assert changed == {"dynamics"}
    for _ in range(3):
        agent.finetune_whole_update(batch.clone())
    changed = {k.split(".")[0] for k, v in agent.world_model.state_dict().items()
               if not torch.equal(v, before[k])}
    assert {"dynamics", "encoder"} <= changed


def test_pretraining_updates_reduce_the_loss():
    agent = _agent(obs_dim=4, action_dim=2, lr=3e-3)
    batch = linear_system_batch(batch=16, time=10, obs_dim=4)
    first = agent.pretrain_update(batch.clone())
    for _ in range(100):
        last = agent.pretrain_update(batch.clone())
    assert last["loss_reward"] < first["loss_reward"] / 2
