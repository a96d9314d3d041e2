"""The quadruped reward's exponent of its upright term: a tilted body pays the plain
upright term raised to the power, upright bodies pay the same, and the option reaches the
dataset's and the recipe's envs (the dataset's rewards: tests/data/test_dataset.py)."""

import numpy as np
import pytest

from simdist.data.dataset import DatasetConfig, make_generation_env, task_kwargs
from simdist.envs import get_target, make_env
from simdist.envs.quadruped import QuadrupedLocomotion
from simdist.pipelines.locomotion import locomotion_env


def pitched_reward(upright_power, pitch_deg, slope_deg=0.0):
    """The reward after the torso is pitched nose-up by ``pitch_deg`` (about the body's y
    axis) at a standstill, with the task's tracking term and the upright term returned."""
    kwargs = {"speeds": (0.5,)}
    if upright_power != 1.0:
        kwargs["upright_power"] = upright_power
    env = make_env("quadruped-slope", num_envs=1, seed=0, task_kwargs={**kwargs,
                                                                      "slope_deg": slope_deg})
    try:
        env.reset()
        sim = env.sims[0]
        half = np.deg2rad(-pitch_deg) / 2  # a negative rotation about y lifts the nose
        sim.physics.data.qpos[3:7] = [np.cos(half), 0.0, np.sin(half), 0.0]
        sim.physics.data.qvel[:] = 0.0
        sim.physics.forward()
        task = sim.task
        rot = sim.physics.data.xmat[task._idx["torso"]].reshape(3, 3)
        upright = (1.0 + rot[:, 2] @ task.ground_normal) / 2.0
        return task.get_reward(sim.physics), upright
    finally:
        env.close()


@pytest.mark.parametrize("pitch_deg", [0.0, 30.0, 60.0])
def test_the_reward_raises_the_upright_term_to_the_power(pitch_deg):
    plain, upright = pitched_reward(1.0, pitch_deg)
    powered, same_upright = pitched_reward(10.0, pitch_deg)
    assert same_upright == pytest.approx(upright)
    assert upright == pytest.approx((1 + np.cos(np.deg2rad(pitch_deg))) / 2, abs=1e-6)
    tracking = plain / upright  # the speed-tracking factor, the same in both envs
    assert 0 < tracking <= 1
    assert powered == pytest.approx(upright ** 10 * tracking, rel=1e-9)


def test_a_30_degree_tilt_pays_about_half_at_power_10_and_most_at_power_1():
    plain, upright = pitched_reward(1.0, 30.0)
    powered, _ = pitched_reward(10.0, 30.0)
    assert upright == pytest.approx(0.933, abs=1e-3)
    assert powered / plain == pytest.approx(upright ** 9, rel=1e-9)
    assert 0.45 < upright ** 10 < 0.55


def test_the_upright_term_is_measured_against_the_slope():
    """On a 12-degree incline a body pitched 12 degrees nose-up stands square to the
    ground: the powered reward keeps all of the tracking term."""
    plain, upright = pitched_reward(1.0, 12.0, slope_deg=12.0)
    powered, _ = pitched_reward(10.0, 12.0, slope_deg=12.0)
    assert upright == pytest.approx(1.0, abs=1e-9)
    assert powered == pytest.approx(plain, rel=1e-9)


def test_an_upright_power_must_be_positive_and_finite():
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="upright_power"):
            QuadrupedLocomotion(upright_power=bad)


def test_the_option_reaches_the_dataset_env_and_the_locomotion_env():
    assert "upright_power" not in task_kwargs(DatasetConfig())  # the control suite's tasks
    env = make_generation_env(DatasetConfig(upright_power=4.0, shard_episodes=2))
    try:
        assert all(sim.task.upright_power == 4.0 for sim in env.sims)
    finally:
        env.close()
    env = locomotion_env(get_target("sim"), 2, 5, seed=0, upright_power=4.0)
    try:
        assert all(sim.task.upright_power == 4.0 for sim in env.base_env.sims)
    finally:
        env.close()
