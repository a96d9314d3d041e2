"""Evaluation in a domain: the expert, the planner, and the per-method results table (forward
progress over the same worlds for every method).
"""

from __future__ import annotations

from tensordict import TensorDict
from tqdm import tqdm

import simdist  # noqa: F401  (headless GL set-up before dm_control)
from simdist.agents import SimDistAgent
from simdist.envs import get_target
from simdist.experts import Expert
from simdist.modules import PlannerConfig
from simdist.pipelines import episode_stats, locomotion_env, rollout
from simdist.pipelines.simdist.config import SIMDIST, STEPS_PER_MINUTE, Config
from simdist.pipelines.simdist.models import planning_agent


def evaluate(cfg: Config, target: str, policy, primers=(), seed_offset: int = 10_000) -> dict:
    """Forward progress of ``policy`` over ``cfg.episodes`` episodes in ``target``.

    Every method is evaluated on the same seeds (same initial states and speeds).
    """
    env = locomotion_env(get_target(target), cfg.episodes, cfg.episode_steps,
                         cfg.seed + seed_offset, primers=primers, task=cfg.task,
                         upright_power=cfg.reward_upright_power)
    stats = episode_stats(rollout(env, policy, cfg.episode_steps, desc=f"evaluate in {target}"),
                          env.base_env.observation_layout)
    env.close()
    return stats


def expert_zero_shot_stage(cfg: Config, expert_path: str) -> dict:
    policy = Expert.load(expert_path).deterministic()
    return {t: evaluate(cfg, t, policy) for t in tqdm(cfg.expert_targets, desc="expert zero-shot")}


def evaluate_planner(cfg: Config, agent: SimDistAgent, target: str,
                     seed_offset: int = 10_000, planner: PlannerConfig | None = None
                     ) -> tuple[dict, TensorDict]:
    """Plans with ``agent``'s world model in ``target`` (with ``planner``, default the
    config's); returns stats and the rollout."""
    planner = planner or cfg.planner()
    env = locomotion_env(get_target(target), cfg.episodes, cfg.episode_steps,
                         cfg.seed + seed_offset, task=cfg.task,
                         upright_power=cfg.reward_upright_power,
                         primers=[agent.make_primer(planner.latency_compensation)])
    spec = env.action_spec
    policy = agent.policy(spec.space.low[0], spec.space.high[0], planner, seed=cfg.seed)
    td = rollout(env, policy, cfg.episode_steps, desc=f"evaluate planner in {target}")
    stats = episode_stats(td, env.base_env.observation_layout)
    env.close()
    return stats, td


def zero_shot_job(cfg: Config, pretrained: dict, domain: str) -> dict:
    """The pretrained planner evaluated in ``domain`` (a :func:`run_jobs` call)."""
    return evaluate_planner(cfg, planning_agent(cfg, pretrained), domain)[0]


def collect_results(cfg, expert_zero_shot, planner_zero_shot, rounds,
                    frozen_parts: dict | None = None) -> dict:
    """Per method: data budget (minutes) -> evaluation stats in the target; and the
    references that do not change with the budget (``simdist.pipelines.report.REFERENCES``:
    the pretrained planner in simulation, the prior alone, the simulator ceiling)."""
    minutes = [0.0] + [r["target_steps"] / STEPS_PER_MINUTE for r in rounds]
    zero = planner_zero_shot[cfg.target]
    expert = expert_zero_shot[cfg.target]
    references = {k: v for k, v in (frozen_parts or {}).items() if v is not None}
    return {
        "minutes": minutes,
        "planner_in_sim": planner_zero_shot["sim"],
        **references,
        "expert (zero-shot)": [expert] * len(minutes),
        SIMDIST: [zero] + [r["simdist_eval"] for r in rounds],
        "ablation: finetune whole model": [zero] + [r["whole_eval"] for r in rounds],
        "baseline: continue expert SAC": [expert] + [r["sac_eval"] for r in rounds],
    }
