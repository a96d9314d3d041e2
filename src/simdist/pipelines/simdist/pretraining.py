"""The pretraining stage (SimDist step 3): the world model, or each ensemble member, on the
perturbed-expert dataset.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import torch

import simdist  # noqa: F401  (headless GL set-up before dm_control)
from simdist.agents import SimDistAgent
from simdist.data import generate_shard, load_dataset
from simdist.objectives.simdist_pretrain import SimDistPretrainLoss, latent_prediction_skill
from simdist.pipelines import mean_metrics, stage_seed, train_resumable
from simdist.pipelines.simdist.config import Config, dataset_config
from simdist.pipelines.simdist.expert_data import load_experts
from simdist.pipelines.simdist.jobs import log_trained, member_jobs, updates_done
from simdist.pipelines.simdist.models import new_agent, save_agent
from simdist.utils import run_jobs, save_atomic


def heldout_prediction_skill(cfg: Config, agent: SimDistAgent, expert_path: str
                             ) -> dict[str, list[float]]:
    """Latent prediction error relative to the latent's variance, per step of the model's
    horizon, on perturbed-expert episodes from seeds the dataset never used, beside the
    no-change and wrong-action references (:func:`latent_prediction_skill`)."""
    data_cfg = dataclasses.replace(dataset_config(cfg), episodes=cfg.heldout_episodes,
                                   shard_episodes=cfg.heldout_episodes, num_workers=1)
    # shard indices past the dataset's own are fresh seeds (see simdist.data.shard_seed)
    episodes = generate_shard(data_cfg, dataset_config(cfg).shards + 1, *load_experts(expert_path))
    with torch.no_grad():
        return latent_prediction_skill(agent.world_model, episodes.to(agent.device),
                                       cfg.model_horizon)


def term_shares(metrics: dict) -> dict:
    """Each loss term's share of the summed loss (how much each shapes the latent)."""
    terms = {k: v for k, v in metrics.items() if k.startswith("loss_")}
    total = sum(terms.values()) or 1.0
    return {k: v / total for k, v in terms.items()}


def member_dir(stage_dir: Path, i: int) -> Path:
    """Member ``i``'s pretraining folder (member 0: the stage folder itself)."""
    return stage_dir if i == 0 else stage_dir / f"member_{i}"


def pretrain_member(cfg: Config, buffer, data, expert_path: str, stage_dir: Path, i: int,
                    logger=None) -> tuple[SimDistAgent, list[dict]]:
    """Member ``i`` of the pretrained ensemble (member 0: the single model of K = 1, its
    initialisation drawn from the generator as the caller left it)."""
    if i:
        torch.manual_seed(stage_seed(cfg.seed, f"pretrain/member_{i}/init"))
    obs = data["observation"]
    shared = cfg.ensemble_size if cfg.ensemble_shared_encoder else 1
    agent = new_agent(cfg, obs.shape[-1], data["action"].shape[-1], dynamics_members=shared)
    flat = obs.reshape(-1, obs.shape[-1])
    agent.world_model.encoder.set_normalisation(flat.mean(0), flat.std(0))
    folder = member_dir(stage_dir, i)
    folder.mkdir(parents=True, exist_ok=True)
    history = train_resumable(
        agent.pretrain_update, lambda: buffer.sample().reshape(-1, cfg.slice_len),
        cfg.pretrain_updates, {"world_model": agent.world_model, "optim": agent.pretrain_optim,
                               **({"extra_dynamics": agent.pretrain_loss.extra_dynamics}
                                  if shared > 1 else {})},
        folder / "training.pt",
        desc="pretrain world model" + (f" (member {i})" if i else ""),
        seed=stage_seed(cfg.seed, "pretrain" if i == 0 else f"pretrain/member_{i}"),
        logger=logger, log_prefix="pretrain" if i == 0 else f"pretrain/member_{i}")
    save_atomic(agent.world_model.state_dict(), folder / "world_model.pt")
    return agent, history


def pretrain_member_job(cfg: Config, dataset: str, expert_path: str, stage_dir: Path,
                        i: int) -> tuple[list[dict], int]:
    """Member ``i``'s pretraining on its own (a :func:`run_jobs` worker), the generator set
    as :func:`pretrain_stage` sets it for member 0, so every member trains as it would in
    the stage's own process; its weights go to its stage folder. Returns its history and
    how many of those updates its checkpoint already held."""
    done = updates_done(member_dir(stage_dir, i) / "training.pt")
    torch.manual_seed(cfg.seed)
    buffer = pretraining_buffer(cfg, dataset)
    return pretrain_member(cfg, buffer, buffer[:], expert_path, stage_dir, i)[1], done


def pretraining_buffer(cfg: Config, dataset: str):
    """The dataset's slices with the entries the pretraining loss reads and no others
    (1.2 ms per sample against 1.8 with every entry; docs/findings.md, "Within 30
    minutes")."""
    keys = dataclasses.astuple(SimDistPretrainLoss.default_keys())
    return load_dataset(dataset, cfg.slice_len, cfg.slice_len * cfg.batch_slices, keys=keys)


def pretrain_stage(cfg: Config, dataset: str, expert_path: str, stage_dir: Path,
                   logger=None) -> dict:
    jobs, threads = member_jobs(cfg)
    if jobs > 1:  # each member in a worker; the loop below then restores them from disk
        histories = run_jobs([(pretrain_member_job, (cfg, dataset, expert_path, stage_dir, i))
                              for i in range(cfg.ensemble_size)], jobs, threads=threads)
        for i, (history, done) in enumerate(histories):
            log_trained(logger, "pretrain" if i == 0 else f"pretrain/member_{i}", history, done)
    torch.manual_seed(cfg.seed)
    buffer = pretraining_buffer(cfg, dataset)
    data = buffer[:]  # the whole memory-mapped dataset (a view: nothing is copied)
    obs = data["observation"]
    agent, history = pretrain_member(cfg, buffer, data, expert_path, stage_dir, 0, logger)
    agent_file = save_agent(cfg, agent, stage_dir / "agent.pt")
    members = [str(stage_dir / "world_model.pt")]
    for i in range(1, cfg.ensemble_size):
        path = member_dir(stage_dir, i) / "world_model.pt"
        if cfg.ensemble_shared_encoder:  # trained above: member 0's parts, dynamics i
            path.parent.mkdir(parents=True, exist_ok=True)
            save_atomic(agent.members()[i].state_dict(), path)
        else:
            pretrain_member(cfg, buffer, data, expert_path, stage_dir, i, logger)
        members.append(str(path))
    first, last = mean_metrics(history[:50], 50), mean_metrics(history)
    skill = heldout_prediction_skill(cfg, agent, expert_path)
    return {"path": members[0], "members": members, "agent": agent_file,
            "obs_dim": obs.shape[-1], "action_dim": data["action"].shape[-1],
            "dynamics_residual": cfg.model_dynamics_residual,
            "prior_bounds": cfg.model_prior_bounds,
            "first": first, "last": last,
            "term_shares_first": term_shares(first), "term_shares_last": term_shares(last),
            "heldout_prediction_error_rel": skill["model"],
            "heldout_prediction_copy_rel": skill["copy"],
            "heldout_prediction_shuffled_rel": skill["shuffled"]}
