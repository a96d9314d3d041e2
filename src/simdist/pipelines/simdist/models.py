"""Building, saving and loading the pipeline's world models (one model, or an ensemble of
members)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import simdist  # noqa: F401  (headless GL set-up before dm_control)
from simdist.agents import SimDistAgent, SimDistConfig, action_bounds
from simdist.envs import make_env
from simdist.modules import SimDistWorldModel, WorldModelEnsemble
from simdist.pipelines.simdist.config import SIMNORM_GROUP, Config, observation_layout
from simdist.utils import RunFolderError, load_checkpoint
from simdist.utils.stages import field_defaults, read_json, read_stage_record


def ignored_inputs(cfg: Config) -> list[int]:
    """Observation indices of ``cfg.model_ignored_observations``."""
    layout = observation_layout(cfg.data_task)
    return sorted(i for g in cfg.model_ignored_observations
                  for i in range(*layout[g].indices(layout.size)))


def new_agent(cfg: Config, obs_dim: int, action_dim: int, dynamics_members: int = 1
              ) -> SimDistAgent:
    overrides = {"history": cfg.model_history} if cfg.model_history else {}
    if cfg.model_dynamics_hidden:
        overrides["dynamics_hidden"] = cfg.model_dynamics_hidden
    if cfg.model_latent_dim:
        overrides.update(latent_dim=cfg.model_latent_dim,
                         simnorm_groups=cfg.model_latent_dim // SIMNORM_GROUP)
    if cfg.model_ignored_observations:
        overrides["ignored_inputs"] = ignored_inputs(cfg)
    if cfg.model_previous_action:
        overrides["previous_action"] = True
    overrides["dynamics_residual"] = cfg.model_dynamics_residual
    if cfg.model_prior_bounds:
        env = make_env(cfg.data_task)
        overrides["prior_bounds"] = action_bounds(env.action_spec)
        env.close()
    wm = SimDistWorldModel.build(obs_dim, action_dim, size=cfg.model_size, **overrides)
    return SimDistAgent(wm, SimDistConfig(size=cfg.model_size, horizon=cfg.model_horizon,
                                          finetune_lr=cfg.finetune_lr,
                                          value_weight=cfg.value_weight,
                                          finetune_reward_weight=cfg.finetune_reward_weight,
                                          finetune_value_weight=cfg.finetune_value_weight,
                                          finetune_consistency=cfg.finetune_consistency,
                                          dynamics_members=dynamics_members,
                                          mixed_precision=cfg.mixed_precision),
                        planner_config=cfg.planner()).to(cfg.device)


def save_agent(cfg: Config, agent: SimDistAgent, path: Path, **meta) -> str:
    """A self-describing agent file (``SimDistAgent.load`` / ``recipes/evaluate.py``)."""
    agent.save(path, optimisers=False, meta={"task": cfg.task, "seed": cfg.seed, **meta})
    return str(path)


def load_finished_run(run: str | Path, **overrides) -> tuple[Config, dict]:
    """The config (with ``overrides``) and the pretrain stage's result of a run folder, for
    tools that reuse a finished run's models (the benchmarks)."""
    run = Path(run)
    stored = read_json(run / "config.json", "recipe config")
    stored = stored.get("config", stored)
    fields = {f.name for f in dataclasses.fields(Config)}
    # a field the folder predates reads as what the folder was made with (StageRunner's rule)
    stored = {**field_defaults(Config), **stored}
    cfg = dataclasses.replace(Config(**{k: v for k, v in stored.items() if k in fields}),
                              **overrides)
    return cfg, read_stage_record(run, "pretrain")["result"]


def load_agent(cfg: Config, pretrained: dict, path: str | None = None) -> SimDistAgent:
    # The two residual forms have the same weights' shapes: a pretraining record copied
    # into a folder of the other form would load without complaint and step wrongly.
    trained = pretrained.get("dynamics_residual", "additive")  # records from before it
    if trained != cfg.model_dynamics_residual:
        raise RunFolderError(
            f"the pretrained dynamics ({pretrained['path']}) was trained with "
            f"--model-dynamics-residual {trained}, this run's config says "
            f"{cfg.model_dynamics_residual}: use the setting the weights were trained with")
    bounded = pretrained.get("prior_bounds", False)
    if bounded != cfg.model_prior_bounds:
        raise RunFolderError(
            f"the pretrained policy prior ({pretrained['path']}) was trained with"
            f"{'' if bounded else ' --no-model-prior-bounds'}"
            f"{' --model-prior-bounds' if bounded else ''}, this run's config says "
            f"otherwise: use the setting the weights were trained with")
    agent = new_agent(cfg, pretrained["obs_dim"], pretrained["action_dim"])
    agent.world_model.load_state_dict(load_checkpoint(path or pretrained["path"]))
    return agent


def member_paths(pretrained: dict, paths: list[str] | None = None) -> list[str]:
    """The ensemble members' weights: ``paths`` if given, else the pretrained ones (a run
    from before ensembles has one member)."""
    return list(paths) if paths else pretrained.get("members", [pretrained["path"]])


def planning_agent(cfg: Config, pretrained: dict, paths: list[str] | None = None
                   ) -> SimDistAgent:
    """The agent the planner runs on: the single model, or the members' ensemble."""
    paths = member_paths(pretrained, paths)
    if len(paths) == 1:
        return load_agent(cfg, pretrained, paths[0])
    members = [load_agent(cfg, pretrained, p).world_model for p in paths]
    return SimDistAgent(WorldModelEnsemble(members), planner_config=cfg.planner()).to(cfg.device)


def pretrained_latent_dim(agent: SimDistAgent) -> int:
    """One member's latent size (the probe's input)."""
    wm = agent.world_model
    return wm.members[0].latent_dim if isinstance(wm, WorldModelEnsemble) else wm.latent_dim
