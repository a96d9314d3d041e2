"""Building blocks of the SimDist quadruped pipeline: envs, rollouts, progress, slices.

Each is a plain function over the library's parts, so the recipe reads top to bottom and
users can recombine the steps (e.g. another target, another policy).
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDict
from torchrl.data import SliceSampler, TensorDictReplayBuffer, TensorStorage
from torchrl.envs import InitTracker, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type
from tqdm import tqdm

from simdist.envs import make_env
from simdist.envs.quadruped import CONTROL_TIMESTEP
from simdist.pipelines.statistics import summarise

UPSIDE_DOWN = -0.5  # body-frame gravity z (1 upright): below it the robot is on its back
TIPPED = 0.5  # body-frame gravity z: below it the body's vertical is 60 degrees off the world's


def locomotion_env(target, episodes: int, steps: int, seed: int, primers=(), task="quadruped-flat",
                   speeds=(0.25, 0.5, 0.75), upside_down_termination: float | None = None,
                   upright_power: float = 1.0):
    """A batched quadruped env (one world per episode) with ``InitTracker`` and primers.

    With ``upside_down_termination`` (see :class:`~simdist.envs.quadruped.QuadrupedLocomotion`)
    a world that rolls onto its back ends its episode and starts a new one within the
    same ``steps`` (its row of a :func:`rollout` then holds several episodes).
    ``upright_power`` is the quadruped reward's exponent of the upright term.
    """
    kwargs = {"speeds": tuple(speeds)}
    if upside_down_termination is not None:
        kwargs["upside_down_termination"] = upside_down_termination
    if upright_power != 1.0:  # a registered robot task's builder need not take it
        kwargs["upright_power"] = float(upright_power)
    env = TransformedEnv(make_env(task, target=target, num_envs=episodes, seed=seed,
                                  max_episode_steps=steps, task_kwargs=kwargs),
                         InitTracker())
    for primer in primers:
        env.append_transform(primer)
    return env


def rollout(env, policy, steps: int, desc: str | None = None) -> TensorDict:
    """``[worlds, steps]``, deterministic exploration mode: one episode per world, unless
    the env ends episodes early (a terminal state), when the world starts another in its row.

    With ``desc``, a progress bar counts the control steps (an evaluation of 32 planned
    episodes takes minutes on a CPU and would otherwise be silent).
    """
    bar = tqdm(total=steps, desc=desc, unit="step", leave=False) if desc else None
    try:
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            return env.rollout(steps, policy, break_when_any_done=False,
                               callback=(lambda *_: bar.update()) if bar else None)
    finally:
        if bar is not None:
            bar.update(steps - bar.n)  # TorchRL skips the callback after the last step
            bar.close()


def progress_stats(td: TensorDict, command_index: int, gravity_z_index: int | None = None
                   ) -> dict:
    """Forward progress per episode (m) and as a fraction of the commanded distance, with
    the fraction's mean, std, IQM and bootstrap 95% CI of the mean over episodes, and each
    episode's commanded speed (``command_mps``: the fraction's mean can hide one speed
    that fails, see :func:`~simdist.pipelines.report.format_by_command`). Given the
    observation index of the body-frame gravity's z, also whether each episode had the
    robot on its back at some step (``upside_down``, below :data:`UPSIDE_DOWN`)."""
    if "is_init" in td.keys() and td["is_init"][:, 1:].any():
        raise ValueError("progress_stats needs one episode per row (is_init is set after a "
                         "row's first step: its world was reset mid-rollout)")
    progress = td["next", "forward_progress"][:, -1, 0]
    command = td["observation"][:, 0, command_index]
    distance = command * td.shape[1] * CONTROL_TIMESTEP
    fraction = (progress / distance).numpy()
    metres = progress.numpy()
    summary = summarise(fraction)
    flips = {}
    if gravity_z_index is not None:  # the readings before and after every step
        z = torch.cat([td["observation"][:, :1, gravity_z_index],
                       td["next", "observation"][..., gravity_z_index]], 1)
        flips["upside_down"] = (z < UPSIDE_DOWN).any(1).tolist()
    return {"progress_m": metres.tolist(), "fraction": fraction.tolist(),
            "command_mps": command.tolist(), **flips,
            "mean_m": float(np.mean(metres)), "std_m": float(np.std(metres)),
            "mean_fraction": summary["mean"], "std_fraction": summary["std"],
            "iqm_fraction": summary["iqm"], "ci_fraction": [summary["ci_low"], summary["ci_high"]],
            "return": float(td["next", "reward"].sum(1).mean())}


def episode_stats(td: TensorDict, layout) -> dict:
    """:func:`progress_stats` with the indices read from the env's observation layout
    (``env.base_env.observation_layout``), so every evaluation also marks the episodes
    that had the robot on its back."""
    return progress_stats(td, layout["command"].start, layout["gravity"].start + 2)


def as_slices(td: TensorDict, slice_len: int, batch_slices: int) -> TensorDictReplayBuffer:
    """An in-memory buffer of ``[episodes, steps]`` data that samples episode-safe slices.

    A slice never spans two rows. A row may hold several episodes (a world reset inside
    the rollout, ``is_init`` set after its first step): a slice can then cross an episode
    start, and the SimDist losses drop every prediction across it
    (:func:`~simdist.objectives.simdist_pretrain.rollout_windows`).
    """
    episodes, steps = td.shape
    data = td.clone()
    data.set("episode", torch.arange(episodes)[:, None].expand(episodes, steps).clone())
    # a fixed buffer: episode boundaries computed once, not at every sample
    sampler = SliceSampler(slice_len=slice_len, traj_key="episode", strict_length=True,
                           cache_values=True)
    return TensorDictReplayBuffer(storage=TensorStorage(data.reshape(-1)), sampler=sampler,
                                  batch_size=slice_len * batch_slices)

