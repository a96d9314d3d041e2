"""The state teacher (TWIST step 1: Dreamer on privileged state, recording the domain-
randomised images of D as it collects), its snapshots, the Oracle and the blind references.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import torch

import simdist  # noqa: F401  (headless GL set-up before dm_control)
from simdist.agents import DreamerAgent
from simdist.agents.checkpoint import read_agent_checkpoint
from simdist.envs import VisualRandomisation
from simdist.pipelines import (ReferencePolicy, control_env, dreamer_keys, evaluate_returns,
                               mean_metrics, snapshot_paths, stage_seed, train_dreamer_online)
from simdist.pipelines.experiment_log import make_logger
from simdist.pipelines.twist.config import REFERENCES, Config, state_dim, training_visual
from simdist.pipelines.twist.readout import readout_file
from simdist.utils import load_checkpoint


def saved_meta(cfg: Config, task: str, seed: int) -> dict:
    """What a saved agent file records besides its weights: the task, the seed and the
    camera its pixels came from, which ``recipes/evaluate.py`` reads (the evaluation
    scenes and seeds are its own flags)."""
    return {"task": task, "seed": seed, "camera_id": cfg.camera_id}


def teacher_agent(cfg: Config, task: str) -> DreamerAgent:
    config = dataclasses.replace(cfg.dreamer(), actor_input_noise=cfg.teacher_actor_noise,
                                 standardise_reconstruction=cfg.teacher_standardise)
    return DreamerAgent.for_state(*state_dim(task), config).to(cfg.device)


def records_images(cfg: Config, task: str) -> bool:
    """Whether the teacher stage renders D's images: only a student that reads them
    needs them (the CNN student, or a readout student trained on the readout's readings),
    unless ``cfg.teacher_pixels`` is ``"always"``."""
    return (cfg.teacher_pixels == "always" or readout_file(cfg, task) is None
            or cfg.readout_student_inputs == "readings")


def teacher_stage(cfg: Config, task: str, seed: int, stage_dir: Path) -> dict:
    """State Dreamer whose collected experience is D, with the domain-randomised image
    of every step when a student reads them (:func:`records_images`)."""
    torch.manual_seed(seed)
    agent = teacher_agent(cfg, task)
    images = records_images(cfg, task)
    env = control_env(task, seed, pixels=images, visual=training_visual(cfg) if images else None,
                      max_episode_steps=cfg.episode_steps, primer=agent.make_primer(),
                      camera_id=cfg.camera_id)
    keys = dreamer_keys("state", "pixels") if images else dreamer_keys("state")
    out = train_dreamer_online(agent, env, cfg.online(), stage_dir,
                               keys, desc=f"teacher {task} s{seed}",
                               seed=stage_seed(seed, f"{task}/teacher"),
                               logger=make_logger(cfg.logger, cfg.output_dir),
                               snapshots=cfg.teacher_snapshots)
    env.close()
    selection = None
    if cfg.teacher_snapshots:
        selection = select_teacher(cfg, task, seed,
                                   snapshot_paths(stage_dir)[-cfg.teacher_snapshots:])
        agent.load_weights(load_checkpoint(selection["chosen"])["weights"], selection["chosen"])
    # the deployed teacher (the chosen snapshot, or the last weights), self-describing: what
    # the Oracle, the students and recipes/evaluate.py load (training.pt is the training
    # checkpoint, which goes on from the last weights)
    agent.save(stage_dir / "teacher_agent.pt", optimisers=False, meta=saved_meta(cfg, task, seed))
    return {"checkpoint": str(stage_dir / "training.pt"), "data": str(stage_dir),
            "agent": str(stage_dir / "teacher_agent.pt"), "selection": selection,
            "images": images,
            "episode_returns": out["episode_returns"], "updates": out["updates"],
            "last": mean_metrics(out["history"])}


def select_teacher(cfg: Config, task: str, seed: int, snapshots: list[Path]) -> dict:
    """The snapshot (weights the teacher stage kept) whose deterministic policy has the
    best mean return over ``cfg.teacher_select_episodes`` state episodes on validation
    seeds drawn for this purpose (not the evaluation's ``seed + 10000``); ties go to the
    later one.

    Returns:
        ``{"chosen": path, "candidates": [{"snapshot": path, "mean": ..., "std": ...}]}``.
    """
    if not snapshots:
        raise RuntimeError("teacher selection: the teacher stage kept no snapshot")
    validation_seed = stage_seed(seed, f"{task}/teacher_selection")
    candidates, agent = [], teacher_agent(cfg, task)
    for path in snapshots:
        agent.load_weights(load_checkpoint(path)["weights"], path)
        stats = evaluate_returns(task, agent.policy(explore=False), agent.make_primer(),
                                 validation_seed, cfg.teacher_select_episodes, cfg.eval_steps,
                                 pixels=False, visual=None)
        candidates.append({"snapshot": str(path), "mean": stats["mean"], "std": stats["std"]})
        print(f"teacher selection {task} s{seed}: {path.name} {stats['mean']:.1f}", flush=True)
    best = max(range(len(candidates)), key=lambda i: (candidates[i]["mean"], i))
    return {"chosen": candidates[best]["snapshot"], "candidates": candidates}


def load_teacher(cfg: Config, task: str, teacher: dict) -> DreamerAgent:
    """The deployed teacher of a finished teacher stage (its ``teacher_agent.pt``)."""
    agent = teacher_agent(cfg, task)
    agent.load_weights(read_agent_checkpoint(teacher["agent"])["weights"], teacher["agent"])
    return agent


def evaluate(cfg: Config, task: str, seed: int, policy, primer, pixels: bool,
             own_scene: bool = False) -> dict:
    """Held-out scenes (textures never seen in training), the same seeds for all methods;
    ``own_scene``: dm_control's own scene instead (where a no-DR baseline trained)."""
    visual = VisualRandomisation.heldout_evaluation() if pixels and not own_scene else None
    return evaluate_returns(task, policy, primer, seed + 10_000, cfg.eval_episodes,
                            cfg.eval_steps, pixels, visual, camera_id=cfg.camera_id)


def last_snapshot(teacher: dict) -> str | None:
    """The path of the last snapshot a finished teacher stage validated, or None when
    there is none or it is the deployed teacher itself."""
    selection = teacher.get("selection")
    if not selection or not selection["candidates"]:
        return None
    last = selection["candidates"][-1]["snapshot"]
    return None if last == selection["chosen"] else last


def snapshot_teacher(cfg: Config, task: str, seed: int, teacher: dict, snapshot: str,
                     stage_dir: Path) -> dict:
    """``teacher`` (a teacher stage's result) with the weights of ``snapshot`` as its
    deployed agent, saved as ``stage_dir/teacher_agent.pt`` (D is the same)."""
    agent = teacher_agent(cfg, task)
    agent.load_weights(load_checkpoint(snapshot)["weights"], snapshot)
    stage_dir.mkdir(parents=True, exist_ok=True)
    agent.save(stage_dir / "teacher_agent.pt", optimisers=False, meta=saved_meta(cfg, task, seed))
    return {**teacher, "agent": str(stage_dir / "teacher_agent.pt")}


def references_stage(cfg: Config, task: str, seed: int) -> dict:
    """Zero and uniform random actions on the Oracle's evaluation seeds (state env: a
    blind policy's return does not depend on the pixels)."""
    action_dim = state_dim(task)[1]
    return {kind: evaluate(cfg, task, seed, ReferencePolicy(kind, action_dim), None,
                           pixels=False) for kind in REFERENCES}
