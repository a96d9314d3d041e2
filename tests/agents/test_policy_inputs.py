"""Every policy acts on an unbatched env (make_env's default) and refuses NaN input by key."""

import pytest
import torch
from torchrl.envs import InitTracker, TransformedEnv

from simdist.agents import (AsymmetricSACAgent, AsymmetricSACConfig, DreamerAgent,
                            DreamerConfig, SimDistAgent, TwistStudent)
from simdist.envs import make_env
from simdist.experts import Expert
from simdist.modules import DreamerWorldModel, PlannerConfig, SimDistWorldModel

PLANNER = PlannerConfig(horizon=2, num_samples=8, num_elites=2, iterations=1)


def _simdist(env):
    agent = SimDistAgent(SimDistWorldModel.build(env.observation_spec["observation"].shape[-1],
                                                 env.action_spec.shape[-1], size="tiny",
                                                 history=2))
    env.append_transform(agent.make_primer(0))
    return agent.policy(action_spec=env.action_spec, config=PLANNER), "observation"


def _dreamer(env):
    agent = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
    env.append_transform(agent.make_primer())
    return agent.policy(explore=False), "state"


def _twist(env):
    teacher = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
    twist = TwistStudent(teacher, DreamerWorldModel.student(1, size="tiny"))
    env.append_transform(twist.make_primer())
    return twist.policy(), "pixels"


def _asymmetric_sac(env):
    return AsymmetricSACAgent(5, 1, AsymmetricSACConfig(depth=4, hidden=16)).policy(
        explore=False), "pixels"


def _expert(env):
    return Expert.untrained(env.observation_spec["observation"].shape[-1],
                            env.action_spec.shape[-1], hidden=16).deterministic(), "observation"


POLICIES = {"simdist": ("quadruped-flat", False, _simdist),
            "dreamer": ("cartpole-balance", False, _dreamer),
            "twist": ("cartpole-balance", True, _twist),
            "asymmetric_sac": ("cartpole-balance", True, _asymmetric_sac),
            "expert": ("quadruped-flat", False, _expert)}


@pytest.mark.parametrize("name", POLICIES)
def test_every_policy_acts_on_an_unbatched_env(name):
    task, pixels, make = POLICIES[name]
    torch.manual_seed(0)
    env = TransformedEnv(make_env(task, pixels=pixels, seed=0), InitTracker())
    assert env.batch_size == ()
    policy, _ = make(env)
    td = env.rollout(3, policy)
    assert td["action"].shape == (3, *env.action_spec.shape)
    assert torch.isfinite(td["action"]).all()
    env.close()


@pytest.mark.parametrize("name", POLICIES)
def test_every_policy_refuses_non_finite_input_naming_the_key(name):
    task, pixels, make = POLICIES[name]
    torch.manual_seed(0)
    env = TransformedEnv(make_env(task, pixels=pixels, seed=0, num_envs=2), InitTracker())
    policy, key = make(env)
    td = env.reset()
    if key == "pixels":  # uint8 frames cannot hold NaN; a float frame can
        td["pixels"] = td["pixels"].float()
    td[key][(0,) * td[key].dim()] = float("nan")  # one entry
    with pytest.raises(ValueError, match=f"'{key}' contains 1 non-finite"):
        policy(td)
    env.close()


@pytest.mark.parametrize("name", ["twist", "asymmetric_sac"])
def test_pixel_policies_refuse_float_images_off_the_encoders_scale_naming_the_key(name):
    """uint8 frames, or floats already in [-0.5, 0.5]; a [0, 1] or [0, 255] float frame
    would be read off-scale without a word, and a wrong shape names the expected one."""
    task, pixels, make = POLICIES[name]
    torch.manual_seed(0)
    env = TransformedEnv(make_env(task, pixels=pixels, seed=0, num_envs=2), InitTracker())
    policy, _ = make(env)
    td = env.reset()
    frames = td["pixels"]
    td["pixels"] = frames.float() / 255.0  # [0, 1]: off the encoders' scale
    with pytest.raises(ValueError, match=r"float 'pixels' must lie in \[-0.5, 0.5\]"):
        policy(td.clone())
    td["pixels"] = frames.float() / 255.0 - 0.5  # the encoders' own scale: accepted
    assert torch.isfinite(policy(td.clone())["action"]).all()
    td["pixels"] = frames.permute(0, 3, 1, 2)  # channels first
    with pytest.raises(ValueError, match=r"'pixels' must end with shape \(64, 64, \d+\)"):
        policy(td.clone())
    env.close()
