"""The pipeline's stages grouped in chains (teacher -> Oracle; each student; each baseline)
that run side by side in worker processes, one run folder for all.
"""

from __future__ import annotations

import simdist  # noqa: F401  (headless GL set-up before dm_control)
from simdist.pipelines.twist.baselines import asymmetric_sac_stage, pixel_dreamer_stage
from simdist.pipelines.twist.config import (ASYMMETRIC_SAC, BASELINE_FIELDS, PIXEL_DREAMERS,
                                            STUDENTS, Config)
from simdist.pipelines.twist.readout import readout_file
from simdist.pipelines.twist.selection import candidate_student_stage, selected_student_stage
from simdist.pipelines.twist.students import student_stage
from simdist.pipelines.twist.teacher import evaluate, load_teacher, references_stage, teacher_stage
from simdist.utils import StageRunner


def stage_runner(cfg: Config) -> StageRunner:
    # tasks, seeds, students and baselines pick which chains run (rows of the table), not
    # what a chain computes: a later run with more of them into the same folder adds them.
    # Without baselines no stage reads the baselines' own settings, so they do not bar a
    # folder.
    ignored = () if cfg.baselines else BASELINE_FIELDS
    return StageRunner(cfg.output_dir, cfg, runtime_keys=(
        "device", "jobs", "logger", "baselines", "students", "tasks", "seeds", *ignored))


def _stage(runner: StageRunner, name: str, fn) -> dict:
    if runner.done(name):
        print(f"stage {name}: already done, reusing its results", flush=True)
    return runner.run(name, fn)


def teacher_chain(cfg: Config, task: str, seed: int) -> None:
    """teacher -> Oracle, and the blind references beside them."""
    runner, key = stage_runner(cfg), f"{task}_s{seed}"
    teacher = _stage(runner, f"{key}_teacher", lambda d: teacher_stage(cfg, task, seed, d))

    def oracle(d):
        agent = load_teacher(cfg, task, teacher)
        return evaluate(cfg, task, seed, agent.policy(explore=False), agent.make_primer(),
                        pixels=False)

    _stage(runner, f"{key}_oracle", oracle)
    _stage(runner, f"{key}_references", lambda d: references_stage(cfg, task, seed))


def student_candidates(cfg: Config, task: str) -> list[str]:
    """The candidate students of ``task``, by name: each of ``readout_student_states``
    (distilled from the deployed teacher), then ``last_<states>`` for each of
    ``student_last_teacher_states`` (from the teacher's last snapshot); none unless a
    readout student has at least two."""
    names = [*cfg.readout_student_states,
             *(f"last_{states}" for states in cfg.student_last_teacher_states)]
    if readout_file(cfg, task) is None or len(names) < 2:
        return []
    return names


def candidate_chain(cfg: Config, task: str, seed: int, suffix: str, name: str) -> None:
    """One candidate of a student of :data:`STUDENTS` (``name``: see
    :func:`student_candidates`)."""
    runner, key = stage_runner(cfg), f"{task}_s{seed}"
    teacher = runner.result(f"{key}_teacher")
    snapshot, states = ("last", name[len("last_"):]) if name.startswith("last_") else ("best", name)
    _stage(runner, f"{key}_{suffix}_{name}", lambda d: candidate_student_stage(
        cfg, task, seed, teacher, STUDENTS[suffix][1], states, d, snapshot))


def student_chain(cfg: Config, task: str, seed: int, suffix: str) -> None:
    """One student of :data:`STUDENTS` (TWIST or an ablation) distilled from the finished
    teacher of ``task`` and ``seed``: the students of one teacher are independent of each
    other, so they run side by side. With candidates (:func:`student_candidates`) it
    deploys the best of their finished stages."""
    runner, key = stage_runner(cfg), f"{task}_s{seed}"
    teacher, overrides = runner.result(f"{key}_teacher"), STUDENTS[suffix][1]
    names = student_candidates(cfg, task)
    if names:
        candidates = {n: runner.result(f"{key}_{suffix}_{n}") for n in names}
        _stage(runner, f"{key}_{suffix}", lambda d: selected_student_stage(
            cfg, task, seed, teacher, overrides, candidates, d))
        return
    _stage(runner, f"{key}_{suffix}",
           lambda d: student_stage(cfg, task, seed, teacher, overrides, d))


def pixel_chain(cfg: Config, task: str, seed: int, suffix: str) -> None:
    """One pixel-Dreamer baseline: independent of the teacher, so it can run beside it."""
    runner = stage_runner(cfg)
    visual = PIXEL_DREAMERS[suffix][1]
    _stage(runner, f"{task}_s{seed}_{suffix}",
           lambda d: pixel_dreamer_stage(cfg, task, seed, visual, d,
                                         state_recon=suffix == "dreamer_state_recon"))


def sac_chain(cfg: Config, task: str, seed: int) -> None:
    """The Asymmetric SAC baseline: independent of the teacher, like the pixel Dreamers."""
    _stage(stage_runner(cfg), f"{task}_s{seed}_{ASYMMETRIC_SAC[0]}",
           lambda d: asymmetric_sac_stage(cfg, task, seed, d))
