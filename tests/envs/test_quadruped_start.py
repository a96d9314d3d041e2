"""The quadruped's episode start: random joint angles that survive the contact-free
placement, and progress that does not count the torso settling onto its legs."""

import numpy as np
import torch

from simdist.envs import TargetDomain, make_env


def test_joint_angles_are_drawn_per_world_and_episode_and_nothing_touches():
    env = make_env("quadruped-flat", num_envs=3, seed=0)
    env.reset()
    angles = []
    for sim in env.sims:
        physics, idx = sim.physics, sim.task._idx
        q = physics.data.qpos[idx["qpos"]].copy()
        assert np.abs(q).max() <= 0.05 and np.abs(q).min() >= 0  # the drawn range
        assert np.abs(q).max() > 0.01  # dm_control's placement used to reset them to 0
        assert physics.data.ncon == 0  # placed above the floor with those angles
        angles.append(q)
    assert not np.allclose(angles[0], angles[1])
    env.reset()
    assert not np.allclose(env.sims[0].physics.data.qpos[env.sims[0].task._idx["qpos"]],
                           angles[0])  # redrawn each episode


def test_progress_on_a_slope_ignores_the_torso_settling():
    # Standing still (zero action, grippy floor): the torso drops several centimetres onto
    # its legs. Progress along the incline must stay ~0, not count the drop's share of it.
    env = make_env("quadruped-flat", target=TargetDomain(slope_deg=12, friction=1.4), seed=0)
    td = env.reset()
    sim = env.sims[0]
    start_z = sim.physics.data.xpos[sim.task._idx["torso"], 2]
    for _ in range(25):
        td["action"] = torch.zeros(12)
        td = env.step(td)["next"]
    drop = start_z - sim.physics.data.xpos[sim.task._idx["torso"], 2]
    assert drop > 0.03
    progress = sim.task.forward_progress(sim.physics)
    assert abs(progress) < 0.3 * drop * np.sin(np.deg2rad(12))
