"""The TorchRL environment: specs, same-step readings, seeding, batching, bad input."""

import functools

import mujoco
import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torchrl.envs import ParallelEnv
from torchrl.envs.utils import check_env_specs

from simdist.envs import (TASKS, DynamicsRandomisation, VisualRandomisation, make_env)


def _actions(env, n, seed=0):
    gen = torch.Generator().manual_seed(seed)
    spec = env.action_spec
    low, high = spec.space.low, spec.space.high
    return [low + (high - low) * torch.rand(low.shape, generator=gen) for _ in range(n)]


def _play(env, actions):
    td = env.reset()
    out = []
    for a in actions:
        td["action"] = a
        td = env.step(td)
        out.append(td["next"].clone())
        td = td["next"]
    return torch.stack(out)


@pytest.mark.parametrize("task", sorted(TASKS))
def test_every_task_passes_torchrl_spec_checks(task):
    env = make_env(task, seed=0)
    check_env_specs(env, seed=0)
    td = env.rollout(3)
    assert td["next", "state"].dtype == torch.float32
    assert td["next", "state"].shape[-1] == env.state_layout.size
    assert torch.isfinite(td["next", "state"]).all()


def test_robot_observation_is_separate_from_privileged_state():
    env = make_env("quadruped-flat", seed=0)
    td = env.reset()
    layout = env.observation_layout
    assert "height_scan" in layout.names() and "joint_pos" in layout.names()
    assert td["observation"].shape == (layout.size,)
    assert "qpos" in env.state_layout.names()  # privileged: absolute pose
    assert "qpos" not in layout.names()


def test_pixels_come_from_the_same_physics_step_as_state():
    env = make_env("quadruped-flat", pixels=True, image_size=32, seed=0)
    steps = _play(env, _actions(env, 6))
    replay = make_env("quadruped-flat", pixels=True, image_size=32, seed=0)
    replay.reset()
    sim = replay.sims[0]
    m, d = sim.physics.model.ptr, sim.physics.data.ptr
    layout = env.state_layout
    frames = steps["pixels"].float()
    for k in (2, 4):
        state = steps[k]["state"].double().numpy()
        d.qpos[:], d.qvel[:] = state[layout["qpos"]], state[layout["qvel"]]
        mujoco.mj_forward(m, d)
        image = torch.from_numpy(sim.render()).float()
        # The state is float32, so a re-render may move an edge pixel; the previous and
        # next frames must be far further away than that.
        same = (image - frames[k]).abs().mean()
        neighbours = min((image - frames[k - 1]).abs().mean(), (image - frames[k + 1]).abs().mean())
        assert same < 0.2 * neighbours, (same, neighbours)


def test_seed_reproduces_rollouts_exactly_with_all_randomisation():
    kwargs = dict(pixels=True, image_size=32,
                  dynamics_randomisation=DynamicsRandomisation(),
                  visual_randomisation=VisualRandomisation.training(camera=True))
    a = make_env("walker-walk", seed=11, **kwargs)
    b = make_env("walker-walk", seed=11, **kwargs)
    actions = _actions(a, 8)
    ra, rb = _play(a, actions), _play(b, actions)
    assert (ra == rb).all()
    c = make_env("walker-walk", seed=12, **kwargs)
    rc = _play(c, actions)
    assert not torch.equal(ra["pixels"], rc["pixels"])
    assert not torch.equal(ra["dynamics"], rc["dynamics"])
    # set_seed restores the same stream on an existing env
    a.set_seed(11)
    assert (_play(a, actions) == ra).all()


@pytest.mark.parametrize("task", ["cheetah-run", "quadruped-flat"])
def test_visual_randomisation_changes_pixels_but_never_physics(task):
    plain = make_env(task, pixels=True, image_size=32, seed=3)
    randomised = make_env(task, pixels=True, image_size=32, seed=3,
                          visual_randomisation=VisualRandomisation.training(camera=True))
    actions = _actions(plain, 6)
    rp, rr = _play(plain, actions), _play(randomised, actions)
    assert torch.equal(rp["state"], rr["state"])
    assert torch.equal(rp["reward"], rr["reward"])
    assert not torch.equal(rp["pixels"], rr["pixels"])
    # every step re-draws the scene: consecutive frames differ beyond the motion alone
    per_step = (rr["pixels"][1:].float() - rr["pixels"][:-1].float()).abs().mean()
    motion = (rp["pixels"][1:].float() - rp["pixels"][:-1].float()).abs().mean()
    assert per_step > 2 * motion


def test_heldout_visuals_are_drawn_once_per_episode():
    env = make_env("cartpole-balance", pixels=True, image_size=32, seed=0,
                   visual_randomisation=VisualRandomisation.heldout_evaluation(camera=False))
    frames = _play(env, [torch.zeros(1)] * 3)["pixels"].float()
    env.reset()
    fresh = env.sims[0].render().astype(np.float32)
    assert (frames[1] - frames[0]).abs().mean() < 2.0  # same scene, cart barely moves
    assert np.abs(fresh - frames[0].numpy()).mean() > 2.0  # new episode, new scene


def test_batched_env_steps_and_partially_resets():
    env = make_env("cartpole-balance", num_envs=3, seed=0, max_episode_steps=4)
    check_env_specs(env, seed=0)
    td = env.rollout(9, break_when_any_done=False)
    assert td.shape == (3, 9)
    done = td["next", "done"].squeeze(-1)
    assert done[:, 3].all() and done[:, 7].all() and not done[:, :3].any()
    reset = env.reset(TensorDict({"_reset": torch.tensor([[True], [False], [True]])}, [3]))
    assert reset.shape == (3,) and not reset["done"].any()


def test_parallel_env_runs_worlds_in_worker_processes():
    env = ParallelEnv(2, functools.partial(make_env, "cartpole-balance", seed=0))
    try:
        td = env.rollout(5)
        assert td.shape == (2, 5)
        assert torch.isfinite(td["next", "state"]).all()
    finally:
        env.close()


def test_collector_with_process_backend():
    from torchrl.collectors import Collector

    collector = Collector(functools.partial(make_env, "cartpole-balance", seed=0), None,
                          frames_per_batch=20, total_frames=40, num_collectors=2,
                          backend="process", sync=True)
    try:
        batches = [b for b in collector]
    finally:
        collector.shutdown()
    assert sum(b.numel() for b in batches) == 40
    assert torch.isfinite(batches[0]["next", "state"]).all()


def test_bad_input_gives_clear_errors():
    with pytest.raises(ValueError, match="unknown task 'pendulum-swing'; valid tasks: .*cartpole"):
        make_env("pendulum-swing")
    with pytest.raises(ValueError, match="valid presets"):
        make_env("cartpole-balance", target="mars")
    with pytest.raises(ValueError, match="pass pixels=True"):
        make_env("cartpole-balance", visual_randomisation=VisualRandomisation.training())
    with pytest.raises(ValueError, match="has no slope"):
        make_env("cartpole-balance", target="slippery_slope")
    with pytest.raises(ValueError, match="num_envs"):
        make_env("cartpole-balance", num_envs=0)
    env = make_env("cartpole-balance")
    td = env.reset()
    td["action"] = torch.tensor([float("nan")])
    with pytest.raises(ValueError, match="non-finite value in 'action'"):
        env.step(td)


@pytest.mark.parametrize("camera_id", [0, 1])  # cartpole: 0 fixed, 1 aims at the cart
def test_camera_rotation_jitter_turns_fixed_and_body_aiming_cameras(camera_id):
    def frame(angle_deg):
        visual = VisualRandomisation(textures=None, colours=None, lighting=False, camera=True,
                                     every_step=False, camera_position_jitter=0.0,
                                     camera_angle_jitter_deg=angle_deg)
        env = make_env("cartpole-balance", pixels=True, image_size=32, seed=4,
                       visual_randomisation=visual, camera_id=camera_id)
        env.reset()
        sim = env.sims[0]
        own = sim.physics.data.cam_xmat[camera_id].copy()
        first, second = sim.render().astype(np.float32), sim.render().astype(np.float32)
        # rendering twice does not rotate twice, and the physics keeps its own view
        assert np.array_equal(first, second)
        np.testing.assert_array_equal(sim.physics.data.cam_xmat[camera_id], own)
        env.close()
        return first

    still, turned = frame(0.0), frame(10.0)
    assert np.abs(turned - still).mean() > 2.0
