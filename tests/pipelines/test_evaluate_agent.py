"""evaluate_agent / record_video for each agent class, in sim and in custom targets."""

import imageio_ffmpeg
import torch

from simdist.agents import DreamerAgent, DreamerConfig, SimDistAgent, TwistStudent
from simdist.envs import make_env
from simdist.modules import DreamerWorldModel, PlannerConfig, SimDistWorldModel
from simdist.pipelines import evaluate_agent, record_video

PLANNER = PlannerConfig(horizon=2, num_samples=8, num_elites=2, iterations=1)


def test_dreamer_results_depend_on_the_target_and_the_seed_alone():
    agent = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
    kwargs = dict(episodes=3, steps=6, seed=2)
    sim = evaluate_agent(agent, "cartpole-balance", "sim", **kwargs)
    torch.manual_seed(123)  # the caller's random state does not leak in
    again = evaluate_agent(agent, "cartpole-balance", "sim", **kwargs)
    assert sim["returns"] == again["returns"] and len(sim["returns"]) == 3
    heavy = evaluate_agent(agent, "cartpole-balance", {"name": "weak", "motor_strength": 0.2},
                           **kwargs)
    assert heavy["target"] == "weak" and heavy["returns"] != sim["returns"]
    assert sim["return"]["ci_low"] <= sim["return"]["mean"] <= sim["return"]["ci_high"]
    assert "progress" not in sim


def test_simdist_agent_reports_forward_progress_in_a_target():
    env = make_env("quadruped-flat", seed=0)
    obs_dim, act_dim = env.observation_spec["observation"].shape[-1], env.action_spec.shape[-1]
    env.close()
    agent = SimDistAgent(SimDistWorldModel.build(obs_dim, act_dim, size="tiny"),
                         planner_config=PLANNER)
    out = evaluate_agent(agent, "quadruped-flat", '{"name": "icy", "friction": 0.4}',
                         episodes=2, steps=5)
    assert out["target"] == "icy" and len(out["progress"]["fraction"]) == 2
    assert set(out["progress"]) >= {"mean_fraction", "iqm_fraction", "ci_fraction"}


def test_twist_student_acts_from_pixels_in_unseen_scenes_and_records_a_video(tmp_path):
    teacher = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
    twist = TwistStudent(teacher, DreamerWorldModel.student(1, size="tiny"))
    out = evaluate_agent(twist, "cartpole-balance", "unseen_scenes", episodes=2, steps=4)
    assert out["target"] == "unseen_scenes" and len(out["returns"]) == 2
    path = record_video(twist, "cartpole-balance", tmp_path / "student.mp4",
                        "unseen_scenes", steps=6, size=64)
    assert imageio_ffmpeg.count_frames_and_secs(str(path))[0] == 7  # reset + 6 steps


def test_asymmetric_sac_agent_acts_from_pixels_without_a_primer():
    from simdist.agents import AsymmetricSACAgent, AsymmetricSACConfig

    agent = AsymmetricSACAgent(5, 1, AsymmetricSACConfig(depth=4, hidden=16))
    out = evaluate_agent(agent, "cartpole-balance", "unseen_scenes", episodes=2, steps=4)
    assert out["target"] == "unseen_scenes" and len(out["returns"]) == 2
