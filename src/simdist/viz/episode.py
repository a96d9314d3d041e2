"""Record one planning episode of a SimDist policy to a rerun ``.rrd`` file."""

from __future__ import annotations

import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from simdist.viz.kinematics import BodyPositions, decode_plans
from simdist.viz.rerun_log import PlanningRecorder

QUADRUPED_BODIES = ("torso", "toe_front_left", "toe_front_right", "toe_back_left",
                    "toe_back_right")


@torch.no_grad()
def record_planning_episode(env, policy, probe, path: str, steps: int,
                            bodies=QUADRUPED_BODIES, application_id: str = "simdist") -> str:
    """Runs ``policy`` (a :class:`~simdist.agents.simdist.SimDistPolicy`) for ``steps`` in
    the first world of ``env`` and logs robot, plan, executed path and reward/value traces.

    ``probe`` maps latents to the privileged state (a ``StateDecoder`` trained with
    :class:`~simdist.objectives.ProbeLoss`); plans are drawn by decoding the planned
    latent trajectory and placing ``bodies`` with MuJoCo kinematics.

    Returns:
        ``path``.
    """
    base = env.base_env
    physics = base.sims[0].physics
    qpos = base.state_layout["qpos"]
    kinematics = BodyPositions(physics.model.ptr, bodies)
    world_model = policy.world_model
    recorder = PlanningRecorder(path, application_id=application_id)
    td = env.reset()
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
            td = step_mdp(td)
    recorder.close()
    return path
