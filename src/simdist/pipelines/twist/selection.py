"""Candidate students and the choice between them (readout students only: chosen by exact-
position validation, which the paper's TWIST does not do).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import torch

import simdist  # noqa: F401  (headless GL set-up before dm_control)
from simdist.agents import TwistStudent
from simdist.pipelines import evaluate_returns, stage_seed
from simdist.pipelines.twist.config import Config
from simdist.pipelines.twist.readout import ExactPositions
from simdist.pipelines.twist.students import build_student, deploy_student, train_student
from simdist.pipelines.twist.teacher import last_snapshot, load_teacher, snapshot_teacher
from simdist.utils import load_checkpoint


def validate_student(cfg: Config, task: str, seed: int, twist: TwistStudent) -> dict:
    """Mean return of a readout student fed exact positions (:class:`ExactPositions`) on
    ``cfg.student_select_episodes`` state episodes of validation seeds drawn for this
    purpose (neither training nor the evaluation's ``seed + 10000``)."""
    stats = evaluate_returns(task, ExactPositions(twist),
                             twist.make_primer(), stage_seed(seed, f"{task}/student_selection"),
                             cfg.student_select_episodes, cfg.eval_steps, pixels=False,
                             visual=None)
    return {"mean": stats["mean"], "std": stats["std"], "returns": stats["returns"]}


def candidate_student_stage(cfg: Config, task: str, seed: int, teacher: dict,
                            overrides: dict, states: str, stage_dir: Path,
                            snapshot: str = "best") -> dict:
    """One candidate readout student, trained on ``states`` of D and validated, distilled
    from the deployed teacher (``snapshot="best"``) or from the teacher stage's last
    snapshot (``"last"``; skipped, with ``validation`` None, when that is the deployed one)."""
    if snapshot == "last":
        last = last_snapshot(teacher)
        if last is None:
            print(f"candidate {stage_dir.name}: the last snapshot is the deployed teacher, "
                  f"skipped", flush=True)
            return {"skipped": "the teacher's last snapshot is its deployed one",
                    "validation": None}
        teacher = snapshot_teacher(cfg, task, seed, teacher, last, stage_dir)
    twist, trained = train_student(cfg, task, seed, teacher, overrides, stage_dir, states)
    validation = validate_student(cfg, task, seed, twist)
    print(f"candidate {stage_dir.name}: validation {validation['mean']:.1f}", flush=True)
    return {**trained, "validation": validation, "teacher_agent": teacher["agent"]}


def select_student(candidates: dict[str, dict]) -> str:
    """The candidate (name -> its stage result) with the best validation mean; ties go to
    the earlier one in ``candidates``' order; skipped candidates (validation None) never."""
    names = [n for n in candidates if candidates[n]["validation"] is not None]
    if not names:
        raise RuntimeError(f"no trained candidate student among {list(candidates)}")
    return max(names, key=lambda n: (candidates[n]["validation"]["mean"], -names.index(n)))


def selected_student_stage(cfg: Config, task: str, seed: int, teacher: dict, overrides: dict,
                           candidates: dict[str, dict], stage_dir: Path) -> dict:
    """Deploys the candidate student with the best validation return (its weights copied
    into this stage as ``student.pt``) and evaluates it from pixels."""
    chosen = select_student(candidates)
    # a candidate of another snapshot deploys with that snapshot's actor
    teacher = {**teacher, "agent": candidates[chosen].get("teacher_agent", teacher["agent"])}
    torch.manual_seed(seed)
    twist = build_student(cfg, task, load_teacher(cfg, task, teacher), overrides)
    state = load_checkpoint(candidates[chosen]["checkpoint"])
    twist.load_state_dict(state["state"]["twist"])
    stage_dir.mkdir(parents=True, exist_ok=True)  # the recording reads the stage's student.pt
    shutil.copyfile(candidates[chosen]["checkpoint"], stage_dir / "student.pt.tmp")
    os.replace(stage_dir / "student.pt.tmp", stage_dir / "student.pt")
    trained = {**candidates[chosen], "checkpoint": str(stage_dir / "student.pt"),
               "teacher_agent": teacher["agent"], "chosen": chosen,
               "candidates": {n: {"checkpoint": c.get("checkpoint"),
                                  "validation": c["validation"]}
                              for n, c in candidates.items()}}
    trained.pop("validation")
    return deploy_student(cfg, task, seed, twist, trained, stage_dir)
