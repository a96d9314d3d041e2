"""TWIST on the control suite, stage by stage: the parts ``recipes/twist_dmc.py`` runs.

One module per concern:

- :mod:`~simdist.pipelines.twist.config`: the typed config (one field per flag) and presets.
- :mod:`~simdist.pipelines.twist.teacher`: the state teacher that records D, the Oracle and
  the blind references (zero and random actions).
- :mod:`~simdist.pipelines.twist.students`: the image student distilled from the frozen
  teacher (Eq. 3 and Eq. 4) and deployed with the teacher's actor.
- :mod:`~simdist.pipelines.twist.readout`: the readout variant's parts (privileged
  supervision; not the paper's TWIST).
- :mod:`~simdist.pipelines.twist.selection`: candidate readout students and the choice.
- :mod:`~simdist.pipelines.twist.baselines`: the pixel Dreamers and Asymmetric SAC.
- :mod:`~simdist.pipelines.twist.recording`: the rerun recording of a student episode.
- :mod:`~simdist.pipelines.twist.chains`: the stages grouped in chains that run side by side.

Examples:
    >>> from simdist.pipelines import twist as pipeline
    >>> cfg = pipeline.Config(**pipeline.PRESETS["tiny"])
    >>> cfg.tasks, cfg.students
    (['cartpole-balance'], ['twist', 'no_imagined', 'no_noise'])
"""

from simdist.pipelines.twist.config import (ASYMMETRIC_SAC, BASELINE_FIELDS, PIXEL_DREAMERS,
                                            PRESETS, READOUT_DIR, READOUT_STUDENTS, REFERENCES,
                                            SAC_FIELDS, STUDENTS, TRAIN_CAMERA_JITTER, TWIST,
                                            Config, saved_config, state_dim, training_visual,
                                            twist_config)
from simdist.pipelines.twist.teacher import (evaluate, last_snapshot, load_teacher, records_images,
                                             references_stage, saved_meta, select_teacher,
                                             snapshot_teacher, teacher_agent, teacher_stage)
from simdist.pipelines.twist.students import (build_student, deploy_student, new_student,
                                              student_stage, train_student)
from simdist.pipelines.twist.readout import (ExactPositions, mask_runs, new_readout_student,
                                             readout_file, readout_positions, readout_training_runs,
                                             recorded_images, student_row, with_positions,
                                             with_readings)
from simdist.pipelines.twist.selection import (candidate_student_stage, select_student,
                                               selected_student_stage, validate_student)
from simdist.pipelines.twist.baselines import asymmetric_sac_stage, pixel_dreamer_stage
from simdist.pipelines.twist.recording import recording_stage
from simdist.pipelines.twist.chains import (candidate_chain, pixel_chain, sac_chain, stage_runner,
                                            student_candidates, student_chain, teacher_chain)

__all__ = [
    "ASYMMETRIC_SAC", "BASELINE_FIELDS", "PIXEL_DREAMERS", "PRESETS", "READOUT_DIR",
    "READOUT_STUDENTS", "REFERENCES", "SAC_FIELDS", "STUDENTS", "TRAIN_CAMERA_JITTER", "TWIST",
    "Config", "saved_config", "state_dim", "training_visual", "twist_config", "evaluate",
    "last_snapshot", "load_teacher", "records_images", "references_stage", "saved_meta",
    "select_teacher", "snapshot_teacher", "teacher_agent", "teacher_stage", "build_student",
    "deploy_student", "new_student", "student_stage", "train_student", "ExactPositions",
    "mask_runs", "new_readout_student", "readout_file", "readout_positions",
    "readout_training_runs", "recorded_images", "student_row", "with_positions",
    "with_readings", "candidate_student_stage", "select_student", "selected_student_stage",
    "validate_student", "asymmetric_sac_stage", "pixel_dreamer_stage", "recording_stage",
    "candidate_chain", "pixel_chain", "sac_chain", "stage_runner", "student_candidates",
    "student_chain", "teacher_chain",
]
