"""A short planning episode recorded to .rrd holds the expected entity paths."""

import numpy as np
import torch
from tensordict import TensorDict

from simdist.envs import make_env
from simdist.modules import SimDistWorldModel, StateDecoder
from simdist.modules.planner import LatentMPPIPlanner, PlannerConfig
from simdist.viz import BodyPositions, PlanningRecorder, decode_plans, entity_paths

BODIES = ["torso", "toe_front_left", "toe_back_right"]


def test_recording_of_a_planning_episode(tmp_path):
    torch.manual_seed(0)
    env = make_env("quadruped-flat", seed=0)
    obs_dim = env.observation_layout.size
    wm = SimDistWorldModel.build(obs_dim, 12, size="tiny", history=1)
    probe = StateDecoder(wm.latent_dim, env.state_layout.size, hidden=16, layers=1)
    planner = LatentMPPIPlanner.from_world_model(
        wm, PlannerConfig(horizon=4, num_samples=16, num_elites=3, iterations=1), seed=0)
    physics = env.sims[0].physics
    bodies = BodyPositions(physics.model.ptr, BODIES)
    path = str(tmp_path / "episode.rrd")
    recorder = PlanningRecorder(path)
    td = env.reset()
    for step in range(3):
        latent = wm.encode(td["observation"][None, None])[0]
        plan = planner(TensorDict({"latent": latent[None]}, [1]))
        mean, elites = plan["planner", "mean"][0], plan["planner", "elite_actions"][0]
        qpos = env.state_layout["qpos"]
        recorder.log_plan(step, decode_plans(wm, probe, latent, mean, qpos, bodies),
                          decode_plans(wm, probe, latent, elites, qpos, bodies), BODIES)
        td["action"] = plan["action"][0]
        td = env.step(td)["next"]
        recorder.log_robot(step, physics.model.ptr, physics.data.ptr, BODIES)
        recorder.log_scalars(step, predicted_reward=plan["planner", "rewards"][0, 0].item(),
                             actual_reward=td["reward"].item(),
                             predicted_value=plan["planner", "value"][0].item())
    recorder.close()
    paths = set(entity_paths(path))
    expected = {"/world/robot/geoms", "/plots/reward/predicted", "/plots/reward/actual",
                "/plots/value/predicted"}
    for name in BODIES:
        expected |= {f"/world/robot/{name}", f"/world/plan/{name}", f"/world/elites/{name}",
                     f"/world/executed/{name}"}
    assert expected <= paths, expected - paths


def test_body_positions_match_the_simulator():
    env = make_env("quadruped-flat", seed=1)
    td = env.rollout(5)
    physics = env.sims[0].physics
    bodies = BodyPositions(physics.model.ptr, BODIES)
    qpos = td["next", "state"][-1, env.state_layout["qpos"]].double().numpy()
    points = bodies(qpos)
    ids = [physics.model.name2id(b, "body") for b in BODIES]
    np.testing.assert_allclose(points, physics.data.xpos[ids], atol=1e-5)


def test_a_recorded_planning_episode_is_also_its_video(tmp_path):
    import imageio_ffmpeg

    from simdist.agents import SimDistAgent
    from simdist.pipelines import locomotion_env
    from simdist.viz import record_planning_episode

    torch.manual_seed(0)
    env = locomotion_env("sim", 1, 4, seed=0)
    obs_dim = env.observation_spec["observation"].shape[-1]
    wm = SimDistWorldModel.build(obs_dim, 12, size="tiny", history=1)
    agent = SimDistAgent(wm, planner_config=PlannerConfig(horizon=2, num_samples=8,
                                                          num_elites=2, iterations=1))
    low, high = env.action_spec.space.low[0], env.action_spec.space.high[0]
    probe = StateDecoder(wm.latent_dim, env.base_env.state_layout.size, hidden=16, layers=1)
    rrd, video = tmp_path / "episode.rrd", tmp_path / "episode.mp4"
    out = record_planning_episode(env, agent.policy(low, high, seed=0), probe, str(rrd), 4,
                                  video_path=video, video_size=64)
    env.close()
    assert out == str(rrd) and "/world/robot/torso" in set(entity_paths(out))
    assert imageio_ffmpeg.count_frames_and_secs(str(video))[0] == 5  # reset + 4 steps
