"""A round of target data (SimDist step 5): collect with the planner, finetune the dynamics
only (SimDist), the whole model (ablation) and the expert's SAC (baseline), evaluate each.
"""

from __future__ import annotations

from pathlib import Path

import torch
from tensordict import TensorDict

import simdist  # noqa: F401  (headless GL set-up before dm_control)
from simdist.data import CoTrainingSlices, load_dataset
from simdist.data.prioritised_slices import PrioritisedSlices, prioritised_update
from simdist.experts import Expert
from simdist.pipelines import (OfflineSAC, OfflineSACConfig, as_slices, mean_metrics, stage_seed,
                               train_resumable)
from simdist.pipelines.simdist.collection import collect_round_data
from simdist.pipelines.simdist.config import FINETUNE_KEYS, STEPS_PER_MINUTE, Config
from simdist.pipelines.simdist.evaluation import evaluate, evaluate_planner
from simdist.pipelines.simdist.jobs import log_trained, member_jobs, stage_jobs, updates_done
from simdist.pipelines.simdist.models import load_agent, member_paths, planning_agent, save_agent
from simdist.utils import load_checkpoint, load_memmap, run_jobs, save_atomic, save_memmap


def member_tag(name: str, i: int) -> str:
    """A method's file stem for member ``i`` (member 0 keeps the single-model name)."""
    return name if i == 0 else f"{name}_member_{i}"


def finetune_member(cfg: Config, k: int, pretrained: dict, path: str, i: int, name: str,
                    what: str, data, sample, stage_dir: Path, logger=None
                    ) -> tuple[str, str, list[dict]]:
    """Member ``i`` of one method of round ``k``: ``cfg.finetune_updates`` resumable updates
    from the weights at ``path``; returns its weights, its agent file and its history."""
    agent = load_agent(cfg, pretrained, path)
    update, optim = ((agent.finetune_update, agent.finetune_optim) if name == "simdist"
                     else (agent.finetune_whole_update, agent.whole_optim))
    state = {"wm": agent.world_model, "opt": optim}
    tag = member_tag(name, i)
    if cfg.finetune_priority_alpha > 0:  # this model's own errors rank the slices
        slices = PrioritisedSlices(data, cfg.slice_len, cfg.batch_slices,
                                   cfg.finetune_priority_alpha, cfg.finetune_priority_beta)
        if not (stage_dir / f"{tag}.ckpt").exists():  # else its checkpoint restores them
            slices.measure_all(agent.finetune_slice_errors)
        sample, update = slices.sample, prioritised_update(update, slices)
        state["priorities"] = slices
    hist = train_resumable(update, sample, cfg.finetune_updates, state,
                           stage_dir / f"{tag}.ckpt",
                           desc=f"round {k + 1}: {what}" + (f" (member {i})" if i else ""),
                           seed=stage_seed(cfg.seed, f"round_{k + 1}/{tag}"),
                           logger=logger, log_prefix=f"round_{k + 1}/{tag}")
    save_atomic(agent.world_model.state_dict(), stage_dir / f"{tag}.pt")
    agent_file = save_agent(cfg, agent, stage_dir / f"{tag}_agent.pt",
                            target=cfg.target, method=name, member=i)
    return str(stage_dir / f"{tag}.pt"), agent_file, hist


def finetune_member_job(cfg: Config, k: int, pretrained: dict, path: str, i: int, name: str,
                        what: str, data_dirs: list[str], dataset: str | None, stage_dir: Path
                        ) -> tuple[str, str, list[dict], int]:
    """:func:`finetune_member` in a :func:`run_jobs` worker, on the round's data read from
    disk; also returns how many updates its checkpoint already held (the caller logs only
    the rest)."""
    done = updates_done(stage_dir / f"{member_tag(name, i)}.ckpt")
    data, sample = round_data(cfg, data_dirs, dataset)
    return (*finetune_member(cfg, k, pretrained, path, i, name, what, data, sample, stage_dir),
            done)


def finetune_and_evaluate(cfg: Config, k: int, pretrained: dict, previous: list[str] | None,
                          name: str, what: str, data, uniform_sample, stage_dir: Path,
                          logger=None, data_dirs: list[str] | None = None,
                          dataset: str | None = None) -> dict:
    """One method of a round for every ensemble member: ``cfg.finetune_updates`` resumable
    updates (``name`` "simdist": dynamics only; "whole": the ablation), weights and a
    self-describing agent file saved per member, then the members' planner evaluated in
    the target. Member 0's files keep the single-model names (``simdist.pt``, ...).

    Slices of ``data`` (``[episodes, steps]``) come from ``uniform_sample``, or with
    ``cfg.finetune_priority_alpha > 0`` from :class:`PrioritisedSlices` ranked by the
    member's own consistency error (measured on every slice before the first update).
    Given ``data_dirs`` (the folders ``data`` was read from) and more than one member,
    the members finetune side by side in worker processes (:func:`member_jobs`)."""
    paths = member_paths(pretrained, previous)
    jobs, threads = member_jobs(cfg, len(paths))
    if jobs > 1 and data_dirs is not None:
        done = run_jobs([(finetune_member_job, (cfg, k, pretrained, path, i, name, what,
                                                data_dirs, dataset, stage_dir))
                         for i, path in enumerate(paths)], jobs, threads=threads)
        for i, (*_, history, before) in enumerate(done):
            log_trained(logger, f"round_{k + 1}/{member_tag(name, i)}", history, before)
    else:
        done = [finetune_member(cfg, k, pretrained, path, i, name, what, data, uniform_sample,
                                stage_dir, logger) for i, path in enumerate(paths)]
    return method_results(cfg, pretrained, name, done)


def method_results(cfg: Config, pretrained: dict, name: str, done: list[tuple]) -> dict:
    """A finetuned method's round entries from its members' ``(weights, agent file,
    history)``, its planner evaluated in the target."""
    saved = [d[0] for d in done]
    agent_files = [d[1] for d in done]
    return {name: saved[0], f"{name}_members": saved,
            f"{name}_agent": agent_files[0], f"{name}_member_agents": agent_files,
            f"{name}_eval": evaluate_planner(cfg, planning_agent(cfg, pretrained, saved),
                                             cfg.target)[0],
            f"{name}_loss": mean_metrics(done[0][2])}


def method_job(cfg: Config, k: int, pretrained: dict, path: str, name: str, what: str,
               data_dirs: list[str], dataset: str | None, stage_dir: Path
               ) -> tuple[dict, list[dict], int]:
    """One finetuned method of a one-model round in a :func:`run_jobs` worker: the model
    at ``path`` finetuned on the round's data read from disk, then evaluated. Returns its
    round entries, its history and how many updates its checkpoint already held."""
    done = updates_done(stage_dir / f"{name}.ckpt")
    data, sample = round_data(cfg, data_dirs, dataset)
    trained = finetune_member(cfg, k, pretrained, path, 0, name, what, data, sample, stage_dir)
    return method_results(cfg, pretrained, name, [trained]), trained[2], done


def previous_members(previous: dict, name: str) -> list[str]:
    """A finished round's weights of method ``name``, one per ensemble member (a round
    recorded before ensembles has one)."""
    return previous.get(f"{name}_members", [previous[name]])


def load_round_data(data_dirs: list[str]) -> TensorDict:
    """Every round's target data so far, ``[episodes, steps]``."""
    return torch.cat([load_memmap(Path(d)) for d in data_dirs], 0)


def round_data(cfg: Config, data_dirs: list[str], dataset: str | None):
    """Every round's target data so far (``[episodes, steps]``, read from ``data_dirs``)
    and the finetuning batch sampler over it; with ``cfg.finetune_sim_fraction > 0`` part
    of every batch comes from the pretraining ``dataset``."""
    data = load_round_data(data_dirs)
    sim_slices = cfg.finetune_sim_slices()
    buffer = as_slices(data, cfg.slice_len, cfg.batch_slices - sim_slices)
    sample = lambda: buffer.sample().reshape(-1, cfg.slice_len)  # noqa: E731
    if sim_slices:  # co-training: part of every batch from the pretraining dataset
        if dataset is None:
            raise ValueError("finetune_sim_fraction > 0 needs the pretraining dataset's path "
                             "(round_stage(dataset=...))")
        sim_buffer = load_dataset(dataset, cfg.slice_len, cfg.slice_len * sim_slices)
        sample = CoTrainingSlices(sample, lambda: sim_buffer.sample().reshape(-1, cfg.slice_len),
                                  keys=FINETUNE_KEYS)
    return data, sample


def round_stage(cfg: Config, k: int, pretrained: dict, expert_path: str, stage_dir: Path,
                previous: dict | None, logger=None, dataset: str | None = None) -> dict:
    """One round: collect with the current SimDist planner, finetune all methods, evaluate.

    ``dataset`` (the pretraining dataset's path) is read only when
    ``cfg.finetune_sim_fraction > 0``."""
    budget = round(cfg.budgets_min[k] * STEPS_PER_MINUTE)
    done_before = previous["target_steps"] if previous else 0
    data_dir = stage_dir / "data"
    previous_simdist = previous and previous_members(previous, "simdist")
    previous_whole = previous and previous_members(previous, "whole")
    if not data_dir.exists():  # save_memmap renames a complete folder into place
        fresh = collect_round_data(cfg, pretrained, previous_simdist, budget - done_before,
                                   seed=cfg.seed + 1000 * (k + 1))
        save_memmap(fresh, data_dir)
    data_dirs = [*(previous["data"] if previous else []), str(data_dir)]
    previous_sac = previous["sac"] if previous else None
    jobs, threads = stage_jobs(cfg, 3)
    simdist_paths = member_paths(pretrained, previous_simdist)
    if jobs > 1 and len(simdist_paths) == 1:
        # one model: SimDist, the ablation and SAC side by side, each in its own process
        methods = [(method_job, (cfg, k, pretrained, simdist_paths[0],
                                 "simdist", "finetune dynamics", data_dirs, dataset, stage_dir)),
                   (method_job, (cfg, k, pretrained, member_paths(pretrained, previous_whole)[0],
                                 "whole", "finetune whole model", data_dirs, dataset, stage_dir)),
                   (sac_job, (cfg, k, expert_path, previous_sac, data_dirs, stage_dir))]
        results = {"target_steps": load_round_data(data_dirs).numel(), "data": data_dirs}
        for tag, (entries, history, before) in zip(("simdist", "whole", "sac"),
                                                   run_jobs(methods, jobs, threads=threads)):
            log_trained(logger, f"round_{k + 1}/{tag}", history, before)
            results.update(entries)
        return results
    data, sample = round_data(cfg, data_dirs, dataset)
    results = {"target_steps": data.numel(), "data": data_dirs}

    # SimDist: dynamics only, continuing from the previous round's dynamics.
    results.update(finetune_and_evaluate(
        cfg, k, pretrained, previous_simdist, "simdist", "finetune dynamics", data, sample,
        stage_dir, logger, data_dirs, dataset))
    # Ablation: the whole world model on the same data, same number of updates.
    results.update(finetune_and_evaluate(
        cfg, k, pretrained, previous_whole, "whole", "finetune whole model", data, sample,
        stage_dir, logger, data_dirs, dataset))
    # Baseline: continue the expert's SAC on the same target data.
    results.update(sac_round(cfg, k, expert_path, previous_sac, data, stage_dir, logger)[0])
    return results


def sac_round(cfg: Config, k: int, expert_path: str, previous_sac: str | None, data,
              stage_dir: Path, logger=None) -> tuple[dict, list[dict]]:
    """The continued-SAC baseline of round ``k``: ``cfg.finetune_updates`` resumable
    updates on the round's ``data`` from the expert (or the previous round's SAC), then
    evaluated in the target. Returns its round entries and its history."""
    sac = OfflineSAC(Expert.load(expert_path),
                     OfflineSACConfig(batch_size=cfg.sac_batch_size, seed=cfg.seed))
    if previous_sac:
        sac.load_state_dict(load_checkpoint(previous_sac)["state"]["sac"])
    sac_buffer = sac.buffer(data)
    hist = train_resumable(sac.update, sac_buffer.sample, cfg.finetune_updates, {"sac": sac},
                           stage_dir / "sac.ckpt", desc=f"round {k + 1}: continue expert SAC",
                           seed=stage_seed(cfg.seed, f"round_{k + 1}/sac"),
                           logger=logger, log_prefix=f"round_{k + 1}/sac")
    return {"sac": str(stage_dir / "sac.ckpt"),
            "sac_eval": evaluate(cfg, cfg.target, sac.expert().deterministic()),
            "sac_loss": mean_metrics(hist)}, hist


def sac_job(cfg: Config, k: int, expert_path: str, previous_sac: str | None,
            data_dirs: list[str], stage_dir: Path) -> tuple[dict, list[dict], int]:
    """:func:`sac_round` in a :func:`run_jobs` worker, on the round's data read from disk;
    also returns how many updates its checkpoint already held."""
    done = updates_done(stage_dir / "sac.ckpt")
    return (*sac_round(cfg, k, expert_path, previous_sac, load_round_data(data_dirs),
                       stage_dir), done)
