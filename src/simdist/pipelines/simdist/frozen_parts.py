"""What the frozen parts can do on their own: SimDist finetunes only the dynamics, so the
encoder, reward, value and policy-prior heads bound what any finetune can reach.

Two references, evaluated in the target on the evaluation worlds' seeds:

- **the policy prior alone** (:func:`prior_only`: one candidate, the prior's own rollout
  without noise, so the action is the prior's at the current latent), every run;
- **the planner with the simulator as its dynamics** (the frozen parts' ceiling:
  :class:`~simdist.pipelines.simulator_dynamics.SimulatorPlanningPolicy`, the same planner
  and heads with MuJoCo in the target in place of the learned dynamics), when
  ``--ceiling-episodes`` asks for it: it steps MuJoCo for every candidate of every
  planning iteration, hundreds of times the cost of the latent planner on a CPU.

The recipe's table prints both beside every budget (``simdist.pipelines.report``).
"""

from __future__ import annotations

import dataclasses

from simdist.envs import get_target
from simdist.modules import PlannerConfig
from simdist.pipelines import episode_stats, locomotion_env, rollout
from simdist.pipelines.simdist.config import Config
from simdist.pipelines.simdist.evaluation import evaluate_planner
from simdist.pipelines.simdist.jobs import stage_jobs
from simdist.pipelines.simdist.models import planning_agent
from simdist.pipelines.simulator_dynamics import SimulatorPlanningPolicy
from simdist.utils import run_jobs


def prior_only(config: PlannerConfig) -> PlannerConfig:
    """``config`` reduced to the policy prior: one noiseless prior rollout per step.

    Examples:
        >>> cfg = prior_only(PlannerConfig(num_samples=64))
        >>> cfg.num_samples, cfg.num_policy, cfg.policy_noise
        (1, 1, 0.0)
    """
    return dataclasses.replace(config, num_samples=1, num_elites=1, iterations=1,
                               policy_fraction=0.9, policy_noise=0.0, proposal_commands=())


def prior_alone_job(cfg: Config, pretrained: dict) -> dict:
    """The prior alone in the target, on the evaluation worlds (a :func:`run_jobs` call)."""
    agent = planning_agent(cfg, pretrained)
    return evaluate_planner(cfg, agent, cfg.target, planner=prior_only(cfg.planner()))[0]


def simulator_ceiling_job(cfg: Config, pretrained: dict) -> dict:
    """The planner with MuJoCo in the target as its dynamics, over the first
    ``cfg.ceiling_episodes`` evaluation worlds (a :func:`run_jobs` call)."""
    agent = planning_agent(cfg, pretrained)
    env = locomotion_env(get_target(cfg.target), cfg.ceiling_episodes, cfg.episode_steps,
                         cfg.seed + 10_000, task=cfg.task,
                         upright_power=cfg.reward_upright_power, primers=[agent.make_primer(0)])
    spec = env.action_spec
    policy = SimulatorPlanningPolicy(agent, env.base_env.sims, cfg.planner(),
                                     spec.space.low[0], spec.space.high[0], seed=cfg.seed)
    td = rollout(env, policy, cfg.episode_steps, desc=f"simulator ceiling in {cfg.target}")
    stats = episode_stats(td, env.base_env.observation_layout)
    env.close()
    return stats


def frozen_parts_stage(cfg: Config, pretrained: dict) -> dict:
    """``{"prior_alone": stats, "simulator_ceiling": stats or None}`` in the target."""
    calls = [(prior_alone_job, (cfg, pretrained))]
    if cfg.ceiling_episodes:
        calls.append((simulator_ceiling_job, (cfg, pretrained)))
    jobs, threads = stage_jobs(cfg, len(calls))
    results = run_jobs(calls, jobs, threads=threads)
    return {"prior_alone": results[0],
            "simulator_ceiling": results[1] if cfg.ceiling_episodes else None}
