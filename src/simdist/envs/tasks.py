"""Task registry: the six TWIST control-suite tasks and quadruped locomotion.

Each :class:`TaskSpec` knows how to build a dm_control physics + task pair for a given
target domain, its control rate, episode length and render camera. Suite tasks are loaded
through ``dm_control.suite`` and then reloaded with small textures (so per-step texture
randomisation is cheap); their privileged ``"state"`` is the suite's state observation,
flattened in key order (what state-based Dreamer and the TWIST teacher use).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from dm_control import suite

from dm_control import mujoco as mujoco_physics

from simdist.envs import manipulation, quadruped
from simdist.envs.layout import Layout
from simdist.envs.targets import TargetDomain


@dataclass(frozen=True)
class TaskSpec:
    """How to build and run one task.

    Attributes:
        name: registry key, ``"<domain>-<task>"``.
        build: ``(target, seed, **task_kwargs) -> (physics, task, n_sub_steps)``, where
            ``n_sub_steps`` physics steps make one control step.
        action_repeat: control steps per agent step.
        max_episode_steps: agent steps before truncation.
        camera_id: default render camera.
        is_robot: whether the task has a robot-measurable ``"observation"`` separate
            from the privileged ``"state"``.
        supports_slope: whether a target's ``slope_deg`` can be honoured.
        defaults: default ``task_kwargs``.

    Examples:
        >>> spec = get_task("cartpole-balance")
        >>> spec.action_repeat, spec.max_episode_steps, spec.is_robot
        (2, 500, False)
        >>> physics, task, n_sub_steps = spec.build(TargetDomain(), seed=0)
        >>> type(task).__name__, n_sub_steps, physics.model.nu
        ('Balance', 1, 1)
    """

    name: str
    build: Callable
    action_repeat: int
    max_episode_steps: int
    camera_id: int
    is_robot: bool = False
    supports_slope: bool = False
    defaults: dict = field(default_factory=dict)


def _suite_builder(domain: str, task: str):
    def build(target: TargetDomain, seed, texture_size: int = 64):
        env = suite.load(domain, task, task_kwargs={"random": seed})
        module = getattr(suite, domain)
        xml, assets = module.get_model_and_assets()
        physics = env.physics
        physics.reload_from_xml_string(xml, quadruped.small_texture_assets(assets, texture_size))
        return physics, env.task, env._n_sub_steps
    return build


def _quadruped_builder(default_slope: float, default_range: tuple | None = None):
    def build(target: TargetDomain, seed, speeds=(0.25, 0.5, 0.75), slope_deg=default_slope,
              slope_range_deg=default_range, upside_down_termination=None,
              upright_power=1.0, texture_size: int = 64):
        # A target's slope is its fixed geometry: it replaces any per-episode range.
        if target.slope_deg:
            slope, slope_range_deg = target.slope_deg, None
        else:
            slope = slope_deg
        xml, assets = quadruped.make_model(slope, texture_size=texture_size)
        physics = quadruped.dmc_quadruped.Physics.from_xml_string(xml, assets)
        task = quadruped.QuadrupedLocomotion(speeds=speeds, slope_deg=slope,
                                             slope_range_deg=slope_range_deg,
                                             upside_down_termination=upside_down_termination,
                                             upright_power=upright_power, random=seed)
        n_sub_steps = int(round(quadruped.CONTROL_TIMESTEP / physics.timestep()))
        return physics, task, n_sub_steps
    return build


# TWIST/DreamerV2 conventions for the control suite: action repeat 2, 1000 physics
# control steps per episode (500 agent steps); camera 0 except quadruped (2).
TASKS: dict[str, TaskSpec] = {
    name: TaskSpec(name, _suite_builder(*name.split("-")), action_repeat=2,
                   max_episode_steps=500, camera_id=0)
    for name in ("ball_in_cup-catch", "cartpole-balance", "cheetah-run", "hopper-stand",
                 "walker-walk", "finger-turn_easy")
}
TASKS["quadruped-flat"] = TaskSpec(
    "quadruped-flat", _quadruped_builder(0.0), action_repeat=1, max_episode_steps=500,
    camera_id=2, is_robot=True, supports_slope=True)
TASKS["quadruped-slope"] = TaskSpec(
    "quadruped-slope", _quadruped_builder(8.0), action_repeat=1, max_episode_steps=500,
    camera_id=2, is_robot=True, supports_slope=True)
# Mixed terrain for training experts and datasets: each episode's incline is drawn
# uniformly in [-15, 15] degrees (forward is downhill below 0), so slopes up to the named
# targets' geometry are in distribution while their dynamics shifts stay outside it.
TASKS["quadruped-terrain"] = TaskSpec(
    "quadruped-terrain", _quadruped_builder(0.0, (-15.0, 15.0)), action_repeat=1,
    max_episode_steps=500, camera_id=2, is_robot=True, supports_slope=True)


def _tabletop_builder(name: str):
    def build(target: TargetDomain, seed, init: str = "narrow", texture_size: int = 64,
              **task_kwargs):
        task_class = manipulation.TASK_CLASSES[name]
        xml, assets = manipulation.make_model(task_class.kind, texture_size)
        physics = mujoco_physics.Physics.from_xml_string(xml, assets)
        task = task_class(init=init, random=seed, **task_kwargs)
        n_sub_steps = int(round(manipulation.CONTROL_TIMESTEP / physics.timestep()))
        return physics, task, n_sub_steps
    return build


# Tabletop manipulation (simdist.envs.manipulation): 20 Hz Cartesian gripper, 150 steps.
for _name in manipulation.TASK_CLASSES:
    TASKS[_name] = TaskSpec(_name, _tabletop_builder(_name), action_repeat=1,
                            max_episode_steps=150, camera_id=0, is_robot=True)


def register_task(spec: TaskSpec, overwrite: bool = False) -> TaskSpec:
    """Adds ``spec`` to :data:`TASKS` under ``spec.name``, so that ``make_env``, the
    dataset generator and the recipes (``--task`` / ``--data-task``) accept it.

    ``spec.build(target, seed, **task_kwargs)`` returns ``(physics, task,
    n_sub_steps)`` for a dm_control ``Physics`` and ``Task``; a robot task
    (``is_robot=True``) also provides the layout protocol the SimDist pipeline reads
    (``observation_layout``, ``state_layout``, ``forward_progress``; see
    ``simdist.envs.quadruped.QuadrupedLocomotion``, the one robot task so far).

    Raises:
        ValueError: the name is taken (pass ``overwrite=True`` to replace it) or is not
            of the ``"<domain>-<task>"`` form.

    Examples:
        >>> spec = TaskSpec("cartpole-swingup", _suite_builder("cartpole", "swingup"),
        ...                 action_repeat=2, max_episode_steps=500, camera_id=0)
        >>> register_task(spec).name in TASKS
        True
        >>> register_task(spec)
        Traceback (most recent call last):
        ...
        ValueError: task 'cartpole-swingup' is already registered; pass overwrite=True to replace it
        >>> _ = TASKS.pop("cartpole-swingup")
    """
    if "-" not in spec.name:
        raise ValueError(f"task names are '<domain>-<task>', got {spec.name!r}")
    if spec.name in TASKS and not overwrite:
        raise ValueError(f"task {spec.name!r} is already registered; pass overwrite=True "
                         "to replace it")
    TASKS[spec.name] = spec
    return spec


def get_task(name: str) -> TaskSpec:
    """Looks up a task, with an error listing the valid names."""
    if name not in TASKS:
        raise ValueError(f"unknown task {name!r}; valid tasks: {', '.join(sorted(TASKS))}")
    return TASKS[name]


def suite_state_layout(task, physics) -> Layout:
    """Layout of a suite task's flattened state observation."""
    obs = task.get_observation(physics)
    return Layout.from_sizes(OrderedDict((k, np.size(v)) for k, v in obs.items()))


def suite_state(task, physics, out: np.ndarray) -> None:
    """Writes a suite task's state observation, flattened in key order, into ``out``."""
    obs = task.get_observation(physics)
    np.concatenate([np.ravel(v) for v in obs.values()], out=out)
