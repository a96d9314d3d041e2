"""Every agent's policy(...) takes the env's TorchRL action spec; old call forms still work."""

import pytest
import torch
from torchrl.data import Bounded, Composite, Unbounded

from simdist.agents import (DreamerAgent, DreamerConfig, SimDistAgent, TwistStudent,
                            action_bounds)
from simdist.envs import make_env
from simdist.modules import DreamerWorldModel, PlannerConfig, SimDistWorldModel

PLANNER = PlannerConfig(horizon=2, num_samples=8, num_elites=2, iterations=1)


def test_simdist_policy_from_an_env_action_spec_equals_explicit_bounds():
    env = make_env("quadruped-flat", num_envs=2, seed=0)
    agent = SimDistAgent(SimDistWorldModel.build(env.observation_spec["observation"].shape[-1],
                                                 env.action_spec.shape[-1], size="tiny"))
    spec = env.action_spec
    by_spec = agent.policy(action_spec=spec, config=PLANNER).planner
    by_bounds = agent.policy(spec.space.low[0], spec.space.high[0], PLANNER).planner
    assert torch.equal(by_spec.action_low, by_bounds.action_low)
    assert torch.equal(by_spec.action_high, by_bounds.action_high)
    assert not torch.equal(by_spec.action_low, -torch.ones_like(by_spec.action_low))
    env.close()


def test_simdist_policy_without_bounds_uses_the_planner_config():
    agent = SimDistAgent(SimDistWorldModel.build(10, 3, size="tiny"))
    planner = agent.policy(config=PlannerConfig(action_low=-0.3, action_high=0.3)).planner
    assert torch.equal(planner.action_high, torch.full((3,), 0.3))


def test_simdist_policy_refuses_ambiguous_bounds():
    agent = SimDistAgent(SimDistWorldModel.build(10, 3, size="tiny"))
    with pytest.raises(ValueError, match="not both"):
        agent.policy(-torch.ones(3), torch.ones(3), action_spec=Bounded(-1.0, 1.0, (3,)))
    with pytest.raises(ValueError, match="both action_low and action_high"):
        agent.policy(-torch.ones(3))


def test_action_bounds_reads_composites_and_refuses_what_it_cannot_plan_in():
    low, high = action_bounds(Composite({"action": Bounded(-2.0, 3.0, (4, 2))}, shape=(4,)))
    assert low.tolist() == [-2.0, -2.0] and high.tolist() == [3.0, 3.0]
    with pytest.raises(ValueError, match="must be bounded"):
        action_bounds(Unbounded((3,)))
    rows = torch.tensor([[-1.0, -1.0], [-2.0, -1.0]])
    with pytest.raises(ValueError, match="different bounds per env"):
        action_bounds(Bounded(rows, torch.ones(2, 2), (2, 2)))


def test_dreamer_and_twist_policies_check_the_unit_box():
    agent = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
    twist = TwistStudent(agent, DreamerWorldModel.student(1, size="tiny"))
    env = make_env("cartpole-balance", num_envs=2, seed=0)
    assert agent.policy(explore=False, action_spec=env.action_spec).noise == 0.0
    assert twist.policy(action_spec=env.action_spec).obs_key == "pixels"
    env.close()
    for make in (lambda s: agent.policy(action_spec=s), lambda s: twist.policy(action_spec=s)):
        with pytest.raises(ValueError, match=r"acts in \[-1, 1\]"):
            make(Bounded(-2.0, 2.0, (1,)))
