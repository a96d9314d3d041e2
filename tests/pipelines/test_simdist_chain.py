"""The SimDist chain on tiny budgets: dataset -> pretrain -> plan in a target -> finetune."""

import pytest
import torch

from simdist.agents import SimDistAgent, SimDistConfig
from simdist.data import DatasetConfig, generate_dataset, load_dataset
from simdist.envs import get_target
from simdist.experts import Expert
from simdist.modules import SimDistWorldModel
from simdist.modules.planner import PlannerConfig
from simdist.pipelines import (as_slices, episode_stats, locomotion_env, progress_stats,
                               rollout)


def test_the_chain_runs_and_finetuning_touches_only_dynamics(tmp_path):
    torch.manual_seed(0)
    expert = Expert.untrained(89, 12, hidden=16)
    data = generate_dataset(DatasetConfig(episodes=4, shard_episodes=4, episode_steps=20),
                            tmp_path / "data", expert, progress=False)
    agent = SimDistAgent(SimDistWorldModel.build(89, 12, size="tiny", history=2),
                         SimDistConfig(horizon=3))
    pretrain_data = load_dataset(data, slice_len=6, batch_size=24)
    for _ in range(3):
        agent.pretrain_update(pretrain_data.sample().reshape(-1, 6))
    env = locomotion_env(get_target("slippery_slope"), episodes=2, steps=8, seed=1,
                         primers=[agent.make_primer()])
    spec = env.action_spec
    policy = agent.policy(spec.space.low[0], spec.space.high[0],
                          PlannerConfig(horizon=3, num_samples=16, num_elites=4, iterations=1))
    target_data = rollout(env, policy, steps=8)
    command = env.base_env.observation_layout["command"].start
    stats = progress_stats(target_data, command_index=command)
    assert (target_data["observation"][:, 0, command] > 0).all()
    assert len(stats["progress_m"]) == 2 and abs(stats["mean_fraction"]) < 10
    # each episode's commanded speed, one of the env's, read from its first observation
    assert stats["command_mps"] == target_data["observation"][:, 0, command].tolist()
    assert set(stats["command_mps"]) <= {0.25, 0.5, 0.75}
    frozen = {k: v.clone() for k, v in agent.world_model.state_dict().items() if not k.startswith("dynamics")}
    finetune_data = as_slices(target_data, slice_len=5, batch_slices=2)
    for _ in range(2):
        agent.finetune_update(finetune_data.sample().reshape(-1, 5))
    assert all(torch.equal(v, frozen[k]) for k, v in agent.world_model.state_dict().items()
               if not k.startswith("dynamics"))


def test_progress_stats_mark_the_episodes_that_had_the_robot_on_its_back():
    env = locomotion_env(get_target("sim"), episodes=3, steps=4, seed=0)
    layout = env.base_env.observation_layout

    def still(td):
        return td.set("action", torch.zeros(3, 12))

    td = env.rollout(4, still, break_when_any_done=False)
    env.close()
    gravity_z = layout["gravity"].start + 2
    # the reading after step t is the observation of step t + 1
    td["next", "observation"][1, 1, gravity_z] = td["observation"][1, 2, gravity_z] = -0.6
    td["next", "observation"][2, 2, gravity_z] = td["observation"][2, 3, gravity_z] = -0.4
    td["next", "observation"][0, 3, gravity_z] = -0.7  # on its back after the last step
    stats = progress_stats(td, layout["command"].start, gravity_z)
    assert stats["upside_down"] == [True, True, False]
    assert episode_stats(td, layout) == stats  # the indices read from the layout
    assert "upside_down" not in progress_stats(td, layout["command"].start)
    td["is_init"][2, 2] = True  # a world reset mid-row: progress would mix two episodes
    with pytest.raises(ValueError, match="one episode per row"):
        progress_stats(td, layout["command"].start)
