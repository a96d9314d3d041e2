"""Target-domain data collected by the planner (the "real" episodes of each round)."""

from __future__ import annotations

import torch
from tensordict import TensorDict

import simdist  # noqa: F401  (headless GL set-up before dm_control)
from simdist.agents import SimDistAgent
from simdist.envs import get_target
from simdist.pipelines import locomotion_env, rollout
from simdist.pipelines.locomotion import UPSIDE_DOWN
from simdist.pipelines.simdist.config import TARGET_KEYS, Config
from simdist.pipelines.simdist.jobs import stage_jobs
from simdist.pipelines.simdist.models import planning_agent
from simdist.utils import run_jobs


def collect_target_data(cfg: Config, agent: SimDistAgent, steps: int, seed: int) -> TensorDict:
    """``steps`` transitions in the target (``[worlds, episode_steps]`` rows) from the
    agent's planner; with ``cfg.collect_reset_upside_down`` a row may hold several
    episodes."""
    return torch.cat([collect_batch(cfg, agent, worlds, batch_seed)
                      for worlds, batch_seed in collection_batches(cfg, steps, seed)], 0)


def collection_batches(cfg: Config, steps: int, seed: int) -> list[tuple[int, int]]:
    """``(worlds, seed)`` of each batch that collects ``steps`` target transitions:
    ``cfg.collect_episodes`` worlds at a time, each batch seeded by its first episode."""
    episodes = max(1, round(steps / cfg.episode_steps))
    return [(min(cfg.collect_episodes, episodes - start), seed + start)
            for start in range(0, episodes, cfg.collect_episodes)]


def collect_batch(cfg: Config, agent: SimDistAgent, worlds: int, seed: int) -> TensorDict:
    """One batch of :func:`collect_target_data`: ``worlds`` episodes stepped at once."""
    env = locomotion_env(get_target(cfg.target), worlds, cfg.episode_steps, seed,
                         task=cfg.task, upright_power=cfg.reward_upright_power,
                         primers=[agent.make_primer(cfg.planner().latency_compensation)],
                         upside_down_termination=(UPSIDE_DOWN if cfg.collect_reset_upside_down
                                                  else None))
    spec = env.action_spec
    policy = agent.policy(spec.space.low[0], spec.space.high[0], cfg.collect_planner(),
                          seed=seed)
    batch = rollout(env, policy, cfg.episode_steps, desc=f"collect in {cfg.target}")
    env.close()
    return batch.select(*TARGET_KEYS)


def collect_batch_job(cfg: Config, pretrained: dict, weights: list[str] | None, worlds: int,
                      seed: int) -> TensorDict:
    """:func:`collect_batch` in a :func:`run_jobs` worker, with the planner on ``weights``
    (None: the pretrained model)."""
    return collect_batch(cfg, planning_agent(cfg, pretrained, weights), worlds, seed)


def collect_round_data(cfg: Config, pretrained: dict, weights: list[str] | None, steps: int,
                       seed: int) -> TensorDict:
    """:func:`collect_target_data` with its batches side by side (:func:`stage_jobs`)."""
    batches = collection_batches(cfg, steps, seed)
    jobs, threads = stage_jobs(cfg, len(batches))
    return torch.cat(run_jobs([(collect_batch_job, (cfg, pretrained, weights, *batch))
                               for batch in batches], jobs, threads=threads), 0)
