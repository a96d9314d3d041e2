"""Building blocks of the TWIST control-suite pipeline: envs, episode replay, returns.

Plain functions over the library's parts, like :mod:`simdist.pipelines.locomotion`, so the
recipe reads top to bottom and users can recombine the steps.
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDict
from torchrl.data import LazyTensorStorage, SliceSampler, TensorDictReplayBuffer
from torchrl.envs import InitTracker, TransformedEnv

from simdist.envs import VisualRandomisation, make_env
from simdist.pipelines.locomotion import rollout

# What a Dreamer/TWIST update reads: the model filters the *next* readings.
DREAMER_KEYS = ["action", "is_init", ("next", "reward"), ("next", "terminated")]


def control_env(task: str, seed: int, *, pixels: bool = False,
                visual: VisualRandomisation | None = None, num_envs: int | None = None,
                max_episode_steps: int | None = None, primer=None, image_size: int = 64,
                camera_id: int | None = None):
    """A control-suite env with ``InitTracker`` (episode starts) and an agent's primer;
    ``camera_id`` renders from another of the model's cameras (None: the task's)."""
    env = TransformedEnv(make_env(task, pixels=pixels, visual_randomisation=visual,
                                  num_envs=num_envs, seed=seed, image_size=image_size,
                                  camera_id=camera_id,
                                  max_episode_steps=max_episode_steps), InitTracker())
    if primer is not None:
        env.append_transform(primer)
    return env


def dreamer_keys(*observations: str) -> list:
    """Keys to keep of a collected episode for Dreamer/TWIST training."""
    return [*DREAMER_KEYS, *[("next", k) for k in observations]]


class EpisodeReplay:
    """Whole episodes in a TorchRL replay buffer, sampled as slices within one episode.

    A thin layer over ``TensorDictReplayBuffer`` + ``SliceSampler(traj_key="episode",
    strict_length=True)``: each added episode gets its own id, so a slice never spans two
    episodes, and ``sample()`` returns ``[slices, slice_len]``.

    Args:
        capacity: transitions kept (oldest dropped first).
        slice_len: steps per slice (TWIST: 50).
        slices: slices per batch (TWIST: 16).

    Examples:
        >>> replay = EpisodeReplay(capacity=100, slice_len=4, slices=3)
        >>> for i in range(2):
        ...     replay.add(TensorDict({"x": torch.full((10, 1), float(i))}, [10]))
        >>> batch = replay.sample()
        >>> batch.shape, bool((batch["x"] == batch["x"][:, :1]).all())  # one episode per slice
        (torch.Size([3, 4]), True)
    """

    def __init__(self, capacity: int, slice_len: int, slices: int):
        self.slice_len, self.episodes = slice_len, 0
        self.buffer = TensorDictReplayBuffer(
            storage=LazyTensorStorage(capacity),
            sampler=SliceSampler(slice_len=slice_len, traj_key="episode", strict_length=True),
            batch_size=slice_len * slices)

    def add(self, episode: TensorDict) -> None:
        if episode.batch_dims != 1:
            raise ValueError(f"add one episode [steps] at a time, got batch {episode.shape}")
        if episode.shape[0] < self.slice_len:
            raise ValueError(f"episode of {episode.shape[0]} steps is shorter than a slice "
                             f"({self.slice_len})")
        episode = episode.clone(False)
        episode.set("episode", torch.full(episode.shape, self.episodes, dtype=torch.long))
        self.buffer.extend(episode)
        self.episodes += 1

    def __len__(self) -> int:
        return len(self.buffer)

    def sample(self) -> TensorDict:
        return self.buffer.sample().reshape(-1, self.slice_len)


def returns_stats(td: TensorDict) -> dict:
    """Per-episode returns of a ``[episodes, steps]`` rollout, with mean and std."""
    returns = td["next", "reward"].sum((1, 2)).numpy()
    return {"returns": returns.tolist(), "mean": float(np.mean(returns)),
            "std": float(np.std(returns))}


def evaluate_returns(task: str, policy, primer, seed: int, episodes: int, steps: int,
                     pixels: bool, visual: VisualRandomisation | None,
                     camera_id: int | None = None) -> dict:
    """Returns of ``policy`` over ``episodes`` parallel worlds (the same seeds for every
    method, so every method meets the same initial states and the same scenes).

    Torch's random draws during the rollout (a Dreamer policy samples its latent) come
    from ``seed`` too, inside a forked generator state: the figure depends on the policy
    and ``seed`` alone, not on what ran before, and the caller's stream is untouched.
    """
    env = control_env(task, seed, pixels=pixels, visual=visual, num_envs=episodes,
                      max_episode_steps=steps, primer=primer, camera_id=camera_id)
    try:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            return returns_stats(rollout(env, policy, steps, desc=f"evaluate {task}"))
    finally:
        env.close()
