"""Online Dreamer training (collect an episode, train on replayed slices), crash-safe.

Used for the TWIST teacher (Dreamer on privileged state that also records the
domain-randomised image of every step, building ``D = {(s, o, a, r)}``) and for the
pixel-Dreamer baselines: the same loop, a different agent and env.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch
from tensordict import TensorDict
from tqdm import tqdm

from simdist.pipelines.control import EpisodeReplay
from simdist.pipelines.locomotion import rollout
from simdist.pipelines.experiment_log import log_metrics
from simdist.pipelines.resumable import stage_seed
from simdist.utils import load_checkpoint, load_memmap, save_atomic, save_memmap


@dataclass
class OnlineConfig:
    """Environment-step budget and replay settings of one online Dreamer run.

    Attributes:
        env_steps: agent steps collected in all (prefill included); whole episodes.
        prefill_steps: of those, steps with uniformly random actions first.
        train_every: agent steps per gradient update (DreamerV2 on DMC: 5).
        episode_steps: agent steps per episode.
        slice_len: replayed slice length; slices: slices per batch.

    Examples:
        >>> cfg = OnlineConfig(env_steps=1200, prefill_steps=500, episode_steps=500)
        >>> cfg.episodes, cfg.prefill_episodes  # whole episodes, rounded up
        (3, 1)
        >>> OnlineConfig(episode_steps=20, slice_len=50)
        Traceback (most recent call last):
        ...
        ValueError: slice_len 50 exceeds episode_steps 20
    """

    env_steps: int = 5000
    prefill_steps: int = 1000
    train_every: int = 5
    episode_steps: int = 500
    slice_len: int = 50
    slices: int = 16

    def __post_init__(self):
        for name in ("env_steps", "train_every", "episode_steps", "slice_len", "slices"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if not 0 <= self.prefill_steps <= self.env_steps:
            raise ValueError("prefill_steps must lie in [0, env_steps]")
        if self.slice_len > self.episode_steps:
            raise ValueError(f"slice_len {self.slice_len} exceeds episode_steps "
                             f"{self.episode_steps}")

    @property
    def episodes(self) -> int:
        return -(-self.env_steps // self.episode_steps)

    @property
    def prefill_episodes(self) -> int:
        return -(-self.prefill_steps // self.episode_steps)


def load_episodes(stage_dir: str | Path) -> list[TensorDict]:
    """The episodes an online run stored (its dataset ``D``), in collection order."""
    folder = Path(stage_dir) / "episodes"
    paths = sorted(p for p in folder.iterdir() if not p.name.endswith(".tmp"))
    return [load_memmap(p) for p in paths]


def snapshot_paths(stage_dir: str | Path) -> list[Path]:
    """The snapshots an online run kept (``snapshots=k``), oldest first; [] if none."""
    folder = Path(stage_dir) / "snapshots"
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir()
                  if p.suffix == ".pt" and not p.name.startswith("."))  # no temp files


def train_dreamer_online(agent, env, config: OnlineConfig, stage_dir: str | Path,
                         keys: list, desc: str = "dreamer", progress: bool = True,
                         seed: int | None = None, logger=None, snapshots: int = 0) -> dict:
    """Alternates collecting one episode with ``agent`` and ``episode_steps / train_every``
    updates on slices of everything collected so far.

    Every episode is written to ``stage_dir/episodes`` (only ``keys``) before it is
    trained on; the agent (weights, optimisers, counters) is checkpointed atomically
    after each episode's updates. Rerunning after a crash reloads the stored episodes,
    restores the agent, and goes on: no episode is collected twice or lost.

    With ``seed``, episode ``i``'s collection (the env's task, dynamics and visual draws,
    and the policy's exploration noise) and its updates (the replay's slices, the
    imagination noise) are each seeded from ``(seed, i)``: a run resumed after a crash at
    any point equals the uninterrupted run on the same device, since nothing depends on
    random state carried over from before the crash.

    With a TorchRL ``logger``, each update's metrics and each episode's return are logged
    under ``desc/``.

    With ``snapshots = k > 0``, the agent's weights after each of the last ``k`` episodes'
    updates are also kept, as ``stage_dir/snapshots/<episode>.pt`` (``{"weights":
    agent.weights()}``, no optimiser state; the last one is the final agent), for a caller
    that picks among them (:func:`snapshot_paths`); the agent must have ``weights()``.

    Args:
        agent: a :class:`~simdist.agents.DreamerAgent` or any agent with the same verbs
            (``policy(explore=True)`` acts, ``update(slices)`` trains, ``state_dict``,
            e.g. :class:`~simdist.agents.AsymmetricSACAgent`); its primer, if any, must
            already be on ``env``.
        env: an unbatched env with ``InitTracker`` whose episodes last
            ``config.episode_steps``.
        keys: the keys of each step to keep (e.g. :func:`~simdist.pipelines.dreamer_keys`).

    Returns:
        ``{"episode_returns": [...], "history": [per-update metrics], "updates": n}``.
    """
    if snapshots < 0:
        raise ValueError(f"snapshots must be >= 0, got {snapshots}")
    stage_dir = Path(stage_dir)
    (stage_dir / "episodes").mkdir(parents=True, exist_ok=True)
    # "training.pt", like every resumable loop's; a folder from before the rename holds the
    # same checkpoint as "agent.pt" (the name agent files use), and resumes from it
    checkpoint = stage_dir / "training.pt"
    if not checkpoint.exists() and (stage_dir / "agent.pt").exists():
        checkpoint = stage_dir / "agent.pt"
    trained, history, returns = 0, [], []
    if checkpoint.exists():
        saved = load_checkpoint(checkpoint)
        agent.load_state_dict(saved["agent"])
        trained, history, returns = saved["episodes"], saved["history"], saved["returns"]
    replay = EpisodeReplay(config.episodes * config.episode_steps, config.slice_len,
                           config.slices)
    updates_per_episode = max(1, config.episode_steps // config.train_every)
    bar = tqdm(range(config.episodes), desc=desc, disable=not progress or
               trained >= config.episodes)
    for i in bar:
        path = stage_dir / "episodes" / f"{i:05d}"
        if not path.exists():
            if seed is not None:
                env.set_seed(stage_seed(seed, f"episode_{i}/env"))
                torch.manual_seed(stage_seed(seed, f"episode_{i}/collect"))
            with torch.no_grad():
                policy = None if i < config.prefill_episodes else agent.policy(explore=True)
                episode = rollout(env, policy, config.episode_steps)
            save_memmap(episode.select(*keys), path)
        episode = load_memmap(path).to_tensordict()
        replay.add(episode)
        if i < trained:
            continue  # collected and trained on before the crash
        returns.append(float(episode["next", "reward"].sum()))
        log_metrics(logger, desc, {"episode_return": returns[-1]}, len(history))
        if seed is not None:
            torch.manual_seed(stage_seed(seed, f"episode_{i}/train"))
        for _ in range(updates_per_episode):
            metrics = agent.update(replay.sample())
            bad = [k for k, v in metrics.items()
                   if k.startswith("loss") and not torch.isfinite(torch.tensor(v))]
            if bad:
                raise FloatingPointError(f"{desc}: non-finite {bad} after episode {i}; last "
                                         f"checkpoint kept at {checkpoint}")
            history.append(metrics)
            log_metrics(logger, desc, metrics, len(history))
        if i >= config.episodes - snapshots:  # before the checkpoint: a crash between
            # the two redoes this episode's updates (seeded) and rewrites the same snapshot
            save_atomic({"weights": agent.weights()}, stage_dir / "snapshots" / f"{i:05d}.pt")
        save_atomic({"agent": agent.state_dict(), "episodes": i + 1, "history": history,
                     "returns": returns}, checkpoint)
        losses = {k: f"{v:.3g}" for k, v in history[-1].items() if k.startswith("loss")}
        bar.set_postfix(episode_return=f"{returns[-1]:.0f}", **dict(list(losses.items())[:2]))
    return {"episode_returns": returns, "history": history, "updates": len(history)}
