"""The quadruped's optional terminal state on its back: the episode ends where the robot
rolled over, and a batched rollout starts that world again while the others go on."""

import pytest
import torch
from torchrl.envs import InitTracker, TransformedEnv

from simdist.envs import make_env
from simdist.envs.quadruped import QuadrupedLocomotion

ON_ITS_BACK = [0.0, 1.0, 0.0, 0.0]  # the free joint's quaternion: 180 degrees about x


def flipping_rollout(upside_down_termination, flip_at=5, steps=12):
    """Two worlds, zero action; world 1 is turned onto its back before step ``flip_at``."""
    kwargs = ({} if upside_down_termination is None
              else {"upside_down_termination": upside_down_termination})
    env = TransformedEnv(make_env("quadruped-flat", num_envs=2, seed=0, max_episode_steps=steps,
                                  task_kwargs=kwargs), InitTracker())
    physics, calls = env.base_env.sims[1].physics, []

    def policy(td):
        calls.append(None)
        if len(calls) == flip_at:
            physics.data.qpos[3:7] = ON_ITS_BACK
            physics.forward()
        return td.set("action", torch.zeros(2, 12))

    try:
        return env.rollout(steps, policy, break_when_any_done=False), env
    finally:
        env.close()


def test_a_world_on_its_back_ends_its_episode_and_starts_a_new_one():
    td, env = flipping_rollout(-0.5)
    terminated = td["next", "terminated"][..., 0]
    assert terminated[1].nonzero().flatten().tolist() == [4]  # the step it was flipped on
    assert not terminated[0].any()
    is_init = td["is_init"][..., 0]
    assert is_init[1].nonzero().flatten().tolist() == [0, 5]  # reset, in the same row
    assert is_init[0].nonzero().flatten().tolist() == [0]
    gravity_z = env.base_env.observation_layout["gravity"].start + 2
    assert td["next", "observation"][1, 4, gravity_z] < -0.5  # the terminal reading
    assert td["observation"][1, 5, gravity_z] > 0.9  # standing again
    assert td.shape == (2, 12)  # the row keeps its length: the step budget is the same


def test_without_the_option_an_episode_on_its_back_runs_to_its_limit():
    td, _ = flipping_rollout(None)
    assert not td["next", "terminated"].any()
    assert td["is_init"][:, 1:].sum() == 0


def test_an_upside_down_threshold_must_be_a_cosine():
    for bad in (-1.0, 1.0, 2.0, float("nan")):
        with pytest.raises(ValueError, match="upside_down_termination"):
            QuadrupedLocomotion(upside_down_termination=bad)
