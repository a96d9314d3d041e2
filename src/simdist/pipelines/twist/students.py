"""The image student (TWIST steps 2-4): distilled from the frozen teacher on slices of D (Eq. 3
and Eq. 4), deployed as pixels -> student latent -> the teacher's actor.
"""

from __future__ import annotations

from pathlib import Path

import torch

import simdist  # noqa: F401  (headless GL set-up before dm_control)
from simdist.agents import DreamerAgent, TwistStudent
from simdist.modules import DreamerWorldModel, ReadoutEncoder, StateReadout
from simdist.pipelines import (EpisodeReplay, load_episodes, mean_metrics, stage_seed,
                               train_resumable)
from simdist.pipelines.experiment_log import make_logger
from simdist.pipelines.twist.config import Config, twist_config
from simdist.pipelines.twist.readout import new_readout_student, readout_file, readout_training_runs
from simdist.pipelines.twist.teacher import evaluate, load_teacher, saved_meta


def new_student(cfg: Config, task: str, teacher: DreamerAgent, overrides: dict) -> TwistStudent:
    student = DreamerWorldModel.student(teacher.actor.action_dim, cfg.model_size,
                                        depth=cfg.student_depth, norm=cfg.student_norm,
                                        input_norm=cfg.student_input_norm,
                                        arch=cfg.student_arch)
    return TwistStudent(teacher, student, twist_config(cfg, overrides)).to(cfg.device)


def build_student(cfg: Config, task: str, teacher: DreamerAgent, overrides: dict) -> TwistStudent:
    """The run's student of ``task``: a readout student if it has a readout, else the CNN."""
    path = readout_file(cfg, task)
    if path is None:
        return new_student(cfg, task, teacher, overrides)
    return new_readout_student(cfg, task, teacher, StateReadout.load(path), overrides)


def train_student(cfg: Config, task: str, seed: int, teacher: dict, overrides: dict,
                  stage_dir: Path, states: str | None = None) -> tuple[TwistStudent, dict]:
    """Distils a student from the frozen teacher on ``D`` (resumable from
    ``stage_dir/student.pt``); a readout student trains on the ``states`` of D ("all" or
    "domain"; default: the config's first). Returns the student and what it trained on."""
    torch.manual_seed(seed)
    agent = load_teacher(cfg, task, teacher)
    twist = build_student(cfg, task, agent, overrides)
    episodes = [e.to_tensordict() for e in load_episodes(teacher["data"])]
    readout, updates, slices = None, cfg.student_updates, cfg.student_slices
    states = states or cfg.readout_student_states[0]
    if isinstance(twist.student.encoder, ReadoutEncoder):
        readout, updates = twist.student.encoder.readout, cfg.readout_student_updates
        slices = cfg.readout_student_slices
        episodes = readout_training_runs(episodes, readout, cfg.student_slice_len,
                                         exact=cfg.readout_student_inputs == "positions",
                                         everywhere=states == "all")
        if not episodes:
            raise RuntimeError(f"the teacher's data holds no run of {cfg.student_slice_len} "
                               f"steps inside the readout's domain {readout.domain}: "
                               f"nothing for a readout student to train on")
    replay = EpisodeReplay(cfg.env_steps + cfg.episode_steps, cfg.student_slice_len, slices)
    for episode in episodes:
        replay.add(episode)
    history = train_resumable(twist.update, replay.sample, updates,
                              {"twist": twist}, stage_dir / "student.pt",
                              every=max(1, updates // 10),
                              desc=f"{stage_dir.name}", seed=stage_seed(seed, stage_dir.name),
                              logger=make_logger(cfg.logger, cfg.output_dir))
    return twist, {"checkpoint": str(stage_dir / "student.pt"), "updates": updates,
                   "student": "readout" if readout is not None else "cnn",
                   "readout": str(readout_file(cfg, task)) if readout is not None else None,
                   "states": states if readout is not None else None,
                   "train_steps": len(replay),
                   "first": mean_metrics(history[:10], 10), "last": mean_metrics(history, 50)}


def deploy_student(cfg: Config, task: str, seed: int, twist: TwistStudent, trained: dict,
                   stage_dir: Path) -> dict:
    """Saves the student as a deployable agent and evaluates it from pixels."""
    # deployable alone (carries the teacher's actor): recipes/evaluate.py --checkpoint
    twist.save(stage_dir / "student_agent.pt", optimisers=False, meta=saved_meta(cfg, task, seed))
    result = evaluate(cfg, task, seed, twist.policy(), twist.make_primer(), pixels=True)
    return {**result, **trained, "agent": str(stage_dir / "student_agent.pt")}


def student_stage(cfg: Config, task: str, seed: int, teacher: dict, overrides: dict,
                  stage_dir: Path) -> dict:
    """Distils a student from the frozen teacher on ``D``, then evaluates it from pixels."""
    twist, trained = train_student(cfg, task, seed, teacher, overrides, stage_dir)
    return deploy_student(cfg, task, seed, twist, trained, stage_dir)
