"""Perturbed-expert datasets on disk: sharded, resumable, memory-mapped.

Layout: ``<dir>/data`` is a memory-mapped TensorDict of shape ``[episodes, steps]``
(episode-major, so every episode is contiguous); ``<dir>/meta.json`` holds the config,
library versions, counts and the shards completed so far. A shard is a batch of
``shard_episodes`` episodes generated from its own seed, so it is the same whenever it
is generated: a killed run, rerun with the same command, regenerates exactly the
unfinished shards - nothing duplicated, nothing lost. (Rows are written through the
memory map before a shard is listed as done; a killed process leaves them in the page
cache, so only a machine crash could lose a listed shard.)
"""

from __future__ import annotations

import dataclasses
import contextlib
import functools
import itertools
import json
import math
import os
import shutil
import time
from dataclasses import dataclass, field
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Sequence

import torch
from tensordict import NestedKey, TensorDict
from tensordict.nn import TensorDictSequential
from torchrl.collectors import Collector
from torchrl.data import SliceSampler, TensorDictReplayBuffer, TensorStorage
from torchrl.envs import InitTracker, ParallelEnv, TransformedEnv
from torchrl.envs.utils import ExplorationType
from tqdm import tqdm

from simdist.data.mixture import EpisodeMixture
from simdist.data.perturbation import ActionPerturbation, PerturbationSchedule
from simdist.envs import DynamicsRandomisation, make_env
from simdist.utils.checkpoint import recovery_hint
from simdist.utils.atomic import write_json_atomic
from simdist.utils.memmap import CorruptDataError, folder_manifest, load_memmap
from simdist.utils.stages import RunFolderError, field_defaults, iter_jobs

_DROP_NEXT = ("observation", "state", "pixels", "dynamics", "perturbation", "mixture", "is_init")


@dataclass
class DatasetConfig:
    """What to generate. ``episodes`` must be a multiple of ``shard_episodes``.

    Examples:
        >>> DatasetConfig(episodes=32, shard_episodes=8).shards
        4
        >>> DatasetConfig(episodes=30, shard_episodes=8)
        Traceback (most recent call last):
        ...
        ValueError: episodes (30) must be a positive multiple of shard_episodes (8)
    """

    task: str = "quadruped-flat"
    episodes: int = 32
    episode_steps: int = 250
    shard_episodes: int = 8
    num_workers: int = 1
    pixels: bool = False
    image_size: int = 64
    dynamics_randomisation: bool = True
    final_expert_probability: float = 0.5
    schedule: PerturbationSchedule = field(default_factory=PerturbationSchedule)
    speeds: tuple = (0.25, 0.5, 0.75)
    # the quadruped task's ``upright_power`` (the reward's exponent of the upright term)
    upright_power: float = 1.0
    seed: int = 0

    def __post_init__(self):
        if self.episodes < 1 or self.shard_episodes < 1 or self.episodes % self.shard_episodes:
            raise ValueError(f"episodes ({self.episodes}) must be a positive multiple of "
                             f"shard_episodes ({self.shard_episodes})")
        if self.num_workers < 1 or self.shard_episodes % self.num_workers:
            # every worker steps the same number of a shard's worlds; name the counts that
            # work so a user with, say, 12 cores need not work them out
            fits = [n for n in range(1, self.shard_episodes + 1) if self.shard_episodes % n == 0]
            raise ValueError(f"shard_episodes ({self.shard_episodes}) must be a multiple of "
                             f"num_workers ({self.num_workers}): with these shards use "
                             f"{fits} workers, or change shard_episodes")
        if self.episode_steps < 2:
            raise ValueError("episode_steps must be >= 2")
        if not 0 <= self.final_expert_probability <= 1:
            raise ValueError("final_expert_probability must lie in [0, 1]")

    @property
    def shards(self) -> int:
        return self.episodes // self.shard_episodes


def _versions() -> dict:
    from simdist import __version__  # the distribution is named simdist-rl, not simdist

    out = {"simdist": __version__}
    for name in ("torch", "torchrl", "tensordict", "mujoco", "dm-control"):
        try:
            out[name] = importlib_metadata.version(name)
        except importlib_metadata.PackageNotFoundError:
            out[name] = None
    return out


def task_kwargs(cfg: DatasetConfig) -> dict:
    """The task options a dataset's env is built with; ``upright_power`` only when it is
    not 1, so tasks without it (the control suite's) keep working.

    Examples:
        >>> task_kwargs(DatasetConfig(upright_power=10.0))
        {'speeds': (0.25, 0.5, 0.75), 'upright_power': 10.0}
    """
    kwargs = {"speeds": tuple(cfg.speeds)}
    if cfg.upright_power != 1.0:
        kwargs["upright_power"] = float(cfg.upright_power)
    return kwargs


def make_generation_env(cfg: DatasetConfig):
    """The env a shard is rolled out in (reused across shards, reseeded for each).

    One process steps ``shard_episodes`` worlds; with ``num_workers > 1`` TorchRL's
    ``ParallelEnv`` spreads them over worker processes (batch ``[workers, per_worker]``)
    while the policy runs batched in this process.
    """
    # The batch, not the env, ends each episode: an env that truncated at the last step
    # would make the collector reset every world there, only for ``reset_at_each_iter``
    # to reset them again before the next shard (one wasted quadruped reset, ~6 ms, per
    # episode). :func:`_label_shard` writes the truncation flags the env would have set.
    make = functools.partial(
        make_env, cfg.task, num_envs=cfg.shard_episodes // cfg.num_workers, seed=cfg.seed,
        pixels=cfg.pixels, image_size=cfg.image_size, max_episode_steps=cfg.episode_steps + 1,
        task_kwargs=task_kwargs(cfg),
        dynamics_randomisation=DynamicsRandomisation() if cfg.dynamics_randomisation else None)
    return make() if cfg.num_workers == 1 else ParallelEnv(cfg.num_workers, make)


def shard_seed(cfg: DatasetConfig, shard: int) -> int:
    """The seed every random draw of ``shard`` derives from (worlds, schedule, mixture)."""
    return cfg.seed * 1_000_003 + shard


class _ShardSeeder:
    """A collector's pre-collect hook: before each batch, reseeds for the next shard.

    Reseeding the env (every world's initial state and randomisation draws) and the
    policy's generators from ``(cfg, shard)`` alone makes a shard the same data whether
    it is the first batch of a fresh collector or the tenth of a long-lived one.
    """

    def __init__(self, cfg: DatasetConfig, shards, env, generators):
        self.cfg, self.env, self.generators = cfg, env, generators
        self._shards = iter(shards)
        self.current: int | None = None

    def __call__(self) -> None:
        self.current = next(self._shards)
        seed = shard_seed(self.cfg, self.current)
        self.env.set_seed(seed)
        for generator in self.generators:
            generator.manual_seed(seed)


def _label_shard(cfg: DatasetConfig, shard: int, td: TensorDict, expert) -> TensorDict:
    """Collector batch ``[*env_batch, T]`` -> stored rows ``[shard_episodes, T]``."""
    td = td.reshape(cfg.shard_episodes, cfg.episode_steps)  # [workers, n, T] -> [E, T]
    with torch.no_grad():
        td.set("value_target", expert.value(td.reshape(-1)).reshape(*td.shape, 1))
    # The policy that acted at step t is the mixture's output there; its input
    # ("mixture", "policy") is the previous step's, i.e. the primer's 0 at an episode start.
    policy = td.get(("next", "mixture", "policy"))
    td.set("policy_index", policy)
    # The BC prior imitates the final expert's own actions only: "not noised" alone would
    # also make it imitate the earlier, weaker snapshots that act in some episodes.
    td.set("noised", ~td.get("expert_active"))
    td.set("expert_active", td.get("expert_active") & (policy.reshape(td.get("expert_active").shape) == 0))
    for key in ("truncated", "done"):  # the episode ends with the batch (make_generation_env)
        td.get(("next", key))[:, -1] = True
    td = td.exclude("collector", "mixture", "perturbation", *[("next", k) for k in _DROP_NEXT])
    episode = torch.arange(cfg.shard_episodes) + shard * cfg.shard_episodes
    # Shaped like the batch (no trailing 1): TorchRL's SliceSampler keys trajectories on it.
    td.set("episode", episode[:, None].expand(td.shape).clone())
    td.set("step", torch.arange(cfg.episode_steps)[None, :].expand(td.shape).clone())
    return td


def collect_shards(cfg: DatasetConfig, shards, expert, snapshots=()):
    """Yields ``(shard, rows)`` for each shard in ``shards``, from one TorchRL ``Collector``.

    One collector batch is one shard: every world runs one whole episode
    (``frames_per_batch = shard_episodes * episode_steps``, the env reset before each
    batch). The policy is the per-episode :class:`EpisodeMixture` of the final expert and
    ``snapshots`` followed by :class:`ActionPerturbation`, run deterministically and
    batched in this process while ``cfg.num_workers`` processes step the worlds. A shard
    depends only on ``(cfg, shard)`` (see :func:`shard_seed`), so a killed run resumes
    exactly, and any backend that calls this gives the same bytes.
    """
    shards = list(shards)
    if not shards:
        return
    env = TransformedEnv(make_generation_env(cfg), InitTracker())
    policies = [expert.deterministic(), *[s.deterministic() for s in snapshots]]
    probs = [1.0] if not snapshots else (
        [cfg.final_expert_probability]
        + [(1 - cfg.final_expert_probability) / len(snapshots)] * len(snapshots))
    mixture = EpisodeMixture(policies, probs)
    # Clamp to the robot's per-joint bounds: the data then records what MuJoCo applied.
    bounds = env.action_spec.space
    perturb = ActionPerturbation(env.action_spec.shape[-1], cfg.schedule,
                                 action_low=bounds.low.reshape(-1, bounds.low.shape[-1])[0],
                                 action_high=bounds.high.reshape(-1, bounds.high.shape[-1])[0])
    env.append_transform(mixture.make_primer())
    env.append_transform(perturb.make_primer())
    seeder = _ShardSeeder(cfg, shards, env, [mixture.generator, perturb.generator])
    frames = cfg.shard_episodes * cfg.episode_steps
    collector = Collector(env, TensorDictSequential(mixture, perturb), frames_per_batch=frames,
                          total_frames=frames * len(shards), reset_at_each_iter=True,
                          exploration_type=ExplorationType.DETERMINISTIC,
                          pre_collect_hook=seeder)
    try:
        for batch in collector:
            yield seeder.current, _label_shard(cfg, seeder.current, batch, expert)
    finally:
        collector.shutdown(raise_on_error=False)  # also closes the env (and its workers)


def generate_shard(cfg: DatasetConfig, shard: int, expert, snapshots=()) -> TensorDict:
    """Rolls out one shard: ``[shard_episodes, episode_steps]`` perturbed-expert steps.

    Examples:
        >>> from simdist.experts import Expert
        >>> cfg = DatasetConfig(episodes=2, shard_episodes=2, episode_steps=5)
        >>> rows = generate_shard(cfg, 0, Expert.untrained(89, 12, hidden=8))
        >>> rows.shape, rows["episode"][:, 0].tolist(), rows["value_target"].shape
        (torch.Size([2, 5]), [0, 1], torch.Size([2, 5, 1]))
    """
    with contextlib.closing(collect_shards(cfg, [shard], expert, snapshots)) as shards:
        return next(shards)[1]


def _ray_shard_task(cfg: DatasetConfig, shard: int, expert, snapshots) -> TensorDict:
    # Runs in a Ray worker: torch there defaults to every core of the node, which
    # oversubscribes when several shards run side by side.
    torch.set_num_threads(1)
    return generate_shard(cfg, shard, expert, snapshots)


def _ray_shards(cfg: DatasetConfig, todo, expert, snapshots, max_in_flight: int | None):
    """Yields ``(shard, data)`` as Ray tasks finish, at most ``max_in_flight`` at once.

    Each task calls :func:`generate_shard` on the same ``(cfg, shard)`` as the local
    backend, so a shard is the same bytes whichever backend made it, and a dataset can
    be started on one backend and resumed on the other.
    """
    try:
        import ray
    except ImportError as err:
        raise ImportError("backend='ray' needs Ray: pip install 'simdist-rl[distributed]'") from err
    if not ray.is_initialized():
        if os.environ.get("RAY_ADDRESS"):  # an existing cluster, as Ray's own tools do
            ray.init(log_to_driver=False)
        else:  # a local cluster over this machine's cores, without the dashboard server
            ray.init(include_dashboard=False, log_to_driver=False)
    task = ray.remote(num_cpus=cfg.num_workers)(_ray_shard_task)
    limit = max_in_flight or max(1, int(ray.available_resources().get("CPU", 1)))
    expert_ref, snapshots_ref = ray.put(expert), ray.put(list(snapshots))
    pending, queue = {}, iter(todo)
    for shard in itertools.islice(queue, limit):
        pending[task.remote(cfg, shard, expert_ref, snapshots_ref)] = shard
    while pending:
        done, _ = ray.wait(list(pending), num_returns=1)
        for shard in itertools.islice(queue, 1):  # keep `limit` shards in flight
            pending[task.remote(cfg, shard, expert_ref, snapshots_ref)] = shard
        yield pending.pop(done[0]), ray.get(done[0])


def _shard_chunk(cfg: DatasetConfig, shards: list[int], expert, snapshots) -> list:
    """``[(shard, rows), ...]`` of :func:`collect_shards` (a worker's call)."""
    return list(collect_shards(cfg, shards, expert, snapshots))


def _shards_side_by_side(cfg: DatasetConfig, todo, expert, snapshots, jobs: int,
                         threads: int | None):
    """Yields ``(shard, rows)`` as ``jobs`` worker processes finish them (the same bytes
    as one collector makes). Each call makes a run of consecutive shards with one
    collector, about four calls per worker: a call pays for building the collector and its
    batched worlds, and one call per shard gained 1.18x over one process against 1.66x
    for runs of shards (docs/findings.md, "Within 30 minutes")."""
    size = max(1, math.ceil(len(todo) / (4 * jobs)))
    chunks = [list(todo[i:i + size]) for i in range(0, len(todo), size)]
    calls = [(_shard_chunk, (cfg, chunk, expert, list(snapshots))) for chunk in chunks]
    with contextlib.closing(iter_jobs(calls, jobs, threads=threads)) as finished:
        for _, rows in finished:
            yield from rows


def generate_dataset(cfg: DatasetConfig, out_dir: str | Path, expert, snapshots=(),
                     progress: bool = True, backend: str = "local",
                     max_in_flight: int | None = None, jobs: int = 1,
                     threads: int | None = None) -> Path:
    """Generates (or resumes) a dataset under ``out_dir``; returns its path.

    Args:
        cfg: what to generate.
        out_dir: the dataset directory; an existing one is resumed (same ``cfg`` only).
        expert: the final :class:`~simdist.experts.Expert` (also labels values).
        snapshots: earlier experts mixed in per episode.
        progress: show a progress bar over shards.
        backend: ``"local"`` rolls shards out in this process (``cfg.num_workers``
            processes step the worlds); ``"ray"`` runs each shard as a Ray task (on the
            cluster ``ray.init`` connected to, or a local one), ``cfg.num_workers`` CPUs
            each. Shards are identical either way; this process writes every row.
        max_in_flight: Ray only: shards generated at once (default: the cluster's CPUs).
        jobs: local only: shards generated side by side, each in one of ``jobs`` spawned
            processes (:func:`~simdist.utils.iter_jobs`) with ``threads`` torch threads
            (default ``cpu_count // jobs``); 1: one collector in this process.
    """
    if backend not in ("local", "ray"):
        raise ValueError(f"unknown backend {backend!r}: use 'local' or 'ray'")
    out = Path(out_dir)
    meta_path = out / "meta.json"
    config = json.loads(json.dumps(dataclasses.asdict(cfg), default=str))
    data = None
    if meta_path.exists():
        meta = read_dataset_meta(out)
        # a field added since the dataset was generated reads as its default (e.g.
        # upright_power: 1.0, the plain reward every older dataset used)
        if {**field_defaults(cfg), **meta["config"]} != config:
            raise RunFolderError(f"{out} holds a dataset generated with a different config; "
                             "use another directory or the same settings to resume")
        # Pre-allocated at full size by the first shard: sizes are checked, never extended.
        data = load_memmap(out / "data")
    else:
        out.mkdir(parents=True, exist_ok=True)
        if (out / "data").exists():  # a run killed before its first shard was recorded
            shutil.rmtree(out / "data")
        meta = {"config": config, "versions": _versions(), "shards_done": [], "seconds": 0.0}
    todo = [s for s in range(cfg.shards) if s not in meta["shards_done"]]
    if backend == "ray":
        shards = _ray_shards(cfg, todo, expert, snapshots, max_in_flight)
    elif jobs > 1:
        shards = _shards_side_by_side(cfg, todo, expert, snapshots, jobs, threads)
    else:
        shards = collect_shards(cfg, todo, expert, snapshots)
    bar = tqdm(total=cfg.shards, initial=cfg.shards - len(todo), disable=not progress,
               desc="dataset shards")
    start = time.perf_counter()
    # closing(): an error while writing still closes the local env / stops the Ray loop
    with contextlib.closing(shards):
        for shard, rows in shards:
            if data is None:  # the first shard fixes the layout of the memory map
                template = rows[:1].expand(cfg.episodes, *rows.shape[1:])
                data = template.memmap_like(out / "data")
            data[shard * cfg.shard_episodes:(shard + 1) * cfg.shard_episodes] = rows
            # Only after the shard's rows are written does the progress file list it.
            meta["shards_done"] = sorted(meta["shards_done"] + [shard])
            now = time.perf_counter()
            meta["seconds"] += now - start
            start = now
            write_json_atomic(meta_path, meta, default=str)
            bar.update(1)
    bar.close()
    files = folder_manifest(out / "data")  # verified by load_dataset before any use
    meta.update(transitions=cfg.episodes * cfg.episode_steps, files=files,
                bytes=sum(f["bytes"] for f in files.values()))
    write_json_atomic(meta_path, meta, default=str)
    return out


def read_dataset_meta(path: str | Path) -> dict:
    """A dataset's ``meta.json``, with an error naming the file if it is missing or corrupt."""
    meta_path = Path(path) / "meta.json"
    if not meta_path.is_file():
        raise FileNotFoundError(f"{meta_path} does not exist: {path} is not a simdist dataset "
                                "(generate one with recipes/generate_dataset.py)")
    try:
        meta = json.loads(meta_path.read_text())
        meta["config"], meta["shards_done"]  # noqa: B018 - the keys every reader needs
    except (ValueError, KeyError, TypeError) as err:
        # inside a run folder the stage record must go too, or the rerun skips the stage
        raise CorruptDataError(f"{meta_path} is corrupt ({err!r}). To recover, "
                               f"{recovery_hint(path)}") from err
    return meta


def load_dataset(path: str | Path, slice_len: int, batch_size: int,
                 keys: Sequence[NestedKey] | None = None) -> TensorDictReplayBuffer:
    """A replay buffer over the memory-mapped dataset that samples whole-episode slices.

    Slices of ``slice_len`` consecutive steps never cross an episode boundary (TorchRL's
    ``SliceSampler`` keyed on ``"episode"``); samples come back as ``[batch, slice_len]``.
    ``keys``: only these entries are stored and sampled (``"episode"`` is always kept), a
    view of the memory map that makes each sample cheaper; default: every entry.
    """
    path = Path(path)
    meta = read_dataset_meta(path)
    cfg = meta["config"]
    if len(meta["shards_done"]) != cfg["episodes"] // cfg["shard_episodes"] or "files" not in meta:
        raise RuntimeError(
            f"{path} is incomplete ({len(meta['shards_done'])} of "
            f"{cfg['episodes'] // cfg['shard_episodes']} shards done): finish it with "
            f"generate_dataset(<same config>, {str(path)!r}) or `python "
            f"recipes/generate_dataset.py` with the same flags and --out {path} (a recipe's "
            "dataset stage does this when its stages/dataset.json record is deleted)")
    data = load_memmap(path / "data", manifest=meta["files"]).reshape(-1)
    if keys is not None:
        data = data.select(*dict.fromkeys([*keys, "episode"]))
    if batch_size % slice_len:
        raise ValueError("batch_size counts transitions: make it a multiple of slice_len")
    # The storage never changes: cache the episodes' boundaries instead of rescanning every
    # row's episode id at each sample (the same slices, 1.9x faster sampling at the
    # recipe's 384k rows on quiet cores; docs/findings.md, "Within 30 minutes").
    sampler = SliceSampler(slice_len=slice_len, traj_key="episode", strict_length=True,
                           cache_values=True)
    buffer = TensorDictReplayBuffer(storage=TensorStorage(data), sampler=sampler,
                                    batch_size=batch_size)
    return buffer
