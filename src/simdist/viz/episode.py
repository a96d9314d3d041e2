"""Record one planning episode of a SimDist policy to a rerun ``.rrd`` file (and an MP4)."""

from __future__ import annotations

import os

import numpy as np
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from simdist.viz.kinematics import BodyPositions, decode_plans
from simdist.viz.rerun_log import PlanningRecorder
from simdist.viz.video import write_mp4

QUADRUPED_BODIES = ("torso", "toe_front_left", "toe_front_right", "toe_back_left",
                    "toe_back_right")


@torch.no_grad()
def record_planning_episode(env, policy, probe, path: str, steps: int,
                            bodies=QUADRUPED_BODIES, application_id: str = "simdist",
                            video_path: str | os.PathLike | None = None,
                            video_size: int = 256) -> str:
    """Runs ``policy`` (a :class:`~simdist.agents.simdist.SimDistPolicy`) for ``steps`` in
    the first world of ``env`` and logs robot, plan, executed path and reward/value traces.

    ``probe`` maps latents to the privileged state (a ``StateDecoder`` trained with
    :class:`~simdist.objectives.ProbeLoss`); plans are drawn by decoding the planned
    latent trajectory and placing ``bodies`` with MuJoCo kinematics.

    With ``video_path`` the same episode is also rendered (``video_size`` px, the reset
    and the state after every step) into an MP4 at the control rate: one episode for
    both, rather than a second run of the planner for the video.

    Returns:
        ``path``.
    """
    base = env.base_env
    sim = base.sims[0]
    physics = sim.physics
    qpos = base.state_layout["qpos"]
    kinematics = BodyPositions(physics.model.ptr, bodies)
    world_model = policy.world_model
    recorder = PlanningRecorder(path, application_id=application_id)
    frames = []
    td = env.reset()
    if video_path is not None:
        frames.append(sim.render(video_size))
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for step in range(steps):
            td = policy(td)
            latent, mean = td["planner", "latent"][0], td["planner", "mean"][0]
            recorder.log_plan(step, decode_plans(world_model, probe, latent, mean, qpos,
                                                 kinematics), names=bodies)
            td = env.step(td)
            recorder.log_robot(step, physics.model.ptr, physics.data.ptr, bodies)
            recorder.log_scalars(step, predicted_reward=td["planner", "rewards"][0, 0].item(),
                                 actual_reward=td["next", "reward"][0].item(),
                                 predicted_value=td["planner", "value"][0].item())
            if video_path is not None:
                frames.append(sim.render(video_size))
            td = step_mdp(td)
    recorder.close()
    if video_path is not None:
        write_mp4(np.stack(frames), video_path, fps=sim.control_rate)
    return path
