"""The rerun recording of one held-out episode: what the student sees and what it believes."""

from __future__ import annotations

from pathlib import Path

import simdist  # noqa: F401  (headless GL set-up before dm_control)
from simdist.envs import VisualRandomisation
from simdist.pipelines import control_env
from simdist.pipelines.twist.config import Config
from simdist.pipelines.twist.students import build_student
from simdist.pipelines.twist.teacher import load_teacher
from simdist.utils import load_checkpoint
from simdist.viz.student_view import record_student_episode


def recording_stage(cfg: Config, task: str, seed: int, teacher: dict, out: Path) -> dict:
    agent = load_teacher(cfg, task, teacher)
    twist = build_student(cfg, task, agent, {})
    twist.load_state_dict(load_checkpoint(out / "stages" / f"{task}_s{seed}_twist" /
                                          "student.pt")["state"]["twist"])
    env = control_env(task, seed + 10_000, pixels=True,
                      visual=VisualRandomisation.heldout_evaluation(),
                      max_episode_steps=cfg.eval_steps, primer=twist.make_primer(),
                      camera_id=cfg.camera_id)
    path = record_student_episode(env, agent, twist, str(out / "rerun_student.rrd"),
                                  cfg.eval_steps)
    env.close()
    return {"path": path}
