"""Evaluate any saved agent in any task and target: returns with mean / IQM / 95% CI, and
forward progress for locomotion; optionally an MP4 of one episode.

Works for every agent class alike (:func:`simdist.agents.load_agent` gives one):
a :class:`~simdist.agents.SimDistAgent` plans within the env's action spec, a
:class:`~simdist.agents.DreamerAgent` acts from ``"state"`` or ``"pixels"``, a
:class:`~simdist.agents.TwistStudent` and an :class:`~simdist.agents.AsymmetricSACAgent`
act from pixels. ``recipes/evaluate.py`` is the
command line over these functions.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch
from torchrl.envs import InitTracker, TransformedEnv

from simdist.agents import AsymmetricSACAgent, DreamerAgent, SimDistAgent, TwistStudent
from simdist.envs import get_target, get_task, make_env
from simdist.experts import Expert
from simdist.modules import PlannerConfig
from simdist.pipelines.locomotion import progress_stats, rollout
from simdist.pipelines.statistics import summarise
from simdist.viz.video import write_mp4


def uses_pixels(agent) -> bool:
    """Whether ``agent`` acts from ``"pixels"`` (a TWIST student or a pixel Dreamer)."""
    return isinstance(agent, TwistStudent) or getattr(agent, "obs_key", None) == "pixels"


def agent_camera(agent, task: str, camera_id: int | None = None) -> int | None:
    """``camera_id``, else for a pixel agent the camera its file records for ``task``
    (``checkpoint_meta["camera_id"]``, written e.g. by the TWIST recipe's ``--camera-id``
    runs), else None (the task's camera).

    Examples:
        >>> from simdist.agents import DreamerAgent, DreamerConfig
        >>> agent = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
        >>> agent_camera(agent, "cartpole-balance") is None, agent_camera(agent, "x", 1)
        (True, 1)
    """
    if camera_id is not None or not uses_pixels(agent):
        return camera_id
    meta = getattr(agent, "checkpoint_meta", None) or {}
    if meta.get("task", task) != task:  # recorded for another task's model
        return None
    return meta.get("camera_id")


def evaluation_env(agent, task: str, target=None, episodes: int = 1, steps: int | None = None,
                   seed: int = 0, image_size: int = 64,
                   camera_id: int | None = None) -> TransformedEnv:
    """``episodes`` batched worlds of ``task`` in ``target`` with ``InitTracker`` and the
    agent's primer; pixels are rendered when the agent or the target needs them, from
    ``camera_id`` (None: the task's camera)."""
    target = get_target(target)
    pixels = uses_pixels(agent) or target.visual is not None
    env = TransformedEnv(make_env(task, target=target, pixels=pixels, num_envs=episodes,
                                  seed=seed, max_episode_steps=steps, image_size=image_size,
                                  camera_id=camera_id),
                         InitTracker())
    primer = agent.make_primer()
    if primer is not None:  # a memoryless actor (Asymmetric SAC) carries nothing
        env.append_transform(primer)
    return env


def agent_policy(agent, env, planner: PlannerConfig | None = None, seed: int = 0):
    """The agent's deterministic policy for ``env`` (``planner`` for a SimDist agent)."""
    if isinstance(agent, SimDistAgent):
        return agent.policy(action_spec=env.action_spec, config=planner, seed=seed)
    if isinstance(agent, (DreamerAgent, TwistStudent, AsymmetricSACAgent, Expert)):
        return agent.policy(explore=False, action_spec=env.action_spec)
    raise TypeError(f"cannot evaluate a {type(agent).__name__}: expected SimDistAgent, "
                    "DreamerAgent, TwistStudent, AsymmetricSACAgent or Expert")


def evaluate_agent(agent, task: str, target=None, episodes: int = 8, steps: int | None = None,
                   seed: int = 0, planner: PlannerConfig | None = None,
                   camera_id: int | None = None) -> dict:
    """Runs ``episodes`` episodes (one per batched world) and summarises them.

    A pixel agent sees ``camera_id``, else the camera its file records for this task
    (:func:`agent_camera`: the TWIST recipe's ``--camera-id`` runs record theirs), else
    the task's camera.

    Torch's random draws (a Dreamer policy samples its latent, a planner seeds from
    ``seed``) come from ``seed`` inside a forked generator state, so the figures depend on
    the agent, task, target and seed alone.

    Returns:
        ``{"task", "target", "episodes", "steps", "seed", "returns": [...],
        "return": summarise(returns)}``, plus ``"progress"``
        (:func:`~simdist.pipelines.progress_stats`) for tasks with a commanded speed.

    Examples:
        >>> from simdist.agents import DreamerAgent, DreamerConfig
        >>> agent = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
        >>> out = evaluate_agent(agent, "cartpole-balance", "sim", episodes=2, steps=5)
        >>> out["target"], len(out["returns"]), sorted(out["return"])[:3]
        ('sim', 2, ['ci_high', 'ci_low', 'iqm'])
    """
    steps = int(steps or get_task(task).max_episode_steps)
    camera_id = agent_camera(agent, task, camera_id)
    env = evaluation_env(agent, task, target, episodes, steps, seed, camera_id=camera_id)
    try:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            td = rollout(env, agent_policy(agent, env, planner, seed), steps)
        layout = env.base_env.observation_layout
        returns = td["next", "reward"].sum((1, 2)).tolist()
        out = {"task": task, "target": get_target(target).name, "episodes": episodes,
               "steps": steps, "seed": seed, "camera_id": camera_id, "returns": returns,
               "return": summarise(returns)}
        if layout is not None and "command" in layout.names():
            out["progress"] = progress_stats(td, layout["command"].start)
        return out
    finally:
        env.close()


def record_video(agent, task: str, path: str | os.PathLike, target=None,
                 steps: int | None = None, seed: int = 0, size: int = 256,
                 fps: float | None = None, planner: PlannerConfig | None = None,
                 camera_id: int | None = None) -> Path:
    """Renders one episode of the agent's deterministic policy at ``size`` px into an MP4.

    ``steps + 1`` frames: the reset and the state after every step, from the task's camera
    or the camera a pixel agent acts from (``camera_id``, else :func:`agent_camera`; not
    its own 64 px view).
    ``fps`` defaults to the task's control rate (real time).

    Examples:
        >>> import tempfile
        >>> from simdist.agents import DreamerAgent, DreamerConfig
        >>> agent = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
        >>> path = record_video(agent, "cartpole-balance", Path(tempfile.mkdtemp()) / "e.mp4",
        ...                     steps=4, size=64)
        >>> path.suffix, path.stat().st_size > 0
        ('.mp4', True)
    """
    steps = int(steps or get_task(task).max_episode_steps)
    env = evaluation_env(agent, task, target, 1, steps, seed,
                         camera_id=agent_camera(agent, task, camera_id))
    sim = env.base_env.sims[0]
    frames = []
    try:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            policy = agent_policy(agent, env, planner, seed)
            with torch.no_grad():
                td = env.reset()
                frames.append(sim.render(size))
                # TorchRL calls the callback after every step but the last one
                env.rollout(steps, policy, auto_reset=False, tensordict=td,
                            break_when_any_done=False,
                            callback=lambda *_: frames.append(sim.render(size)))
                frames.append(sim.render(size))
    finally:
        env.close()
    return write_mp4(np.stack(frames), path, sim.control_rate if fps is None else fps)
