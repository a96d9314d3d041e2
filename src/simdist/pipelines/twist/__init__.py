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

from simdist.pipelines.twist.config import (TWIST, STUDENTS, ASYMMETRIC_SAC, REFERENCES,
                                            PIXEL_DREAMERS, Config, PRESETS,
                                            TRAIN_CAMERA_JITTER, saved_config, training_visual,
                                            state_dim, twist_config, READOUT_DIR, SAC_FIELDS,
                                            BASELINE_FIELDS)
from simdist.pipelines.twist.teacher import (saved_meta, teacher_agent, records_images,
                                             teacher_stage, select_teacher, load_teacher,
                                             evaluate, last_snapshot, snapshot_teacher,
                                             references_stage)
from simdist.pipelines.twist.students import (new_student, build_student, train_student,
                                              deploy_student, student_stage)
from simdist.pipelines.twist.readout import (readout_file, new_readout_student, mask_runs,
                                             with_readings, recorded_images, with_positions,
                                             readout_positions, readout_training_runs,
                                             ExactPositions)
from simdist.pipelines.twist.selection import (validate_student, candidate_student_stage,
                                               select_student, selected_student_stage)
from simdist.pipelines.twist.baselines import (pixel_dreamer_stage, asymmetric_sac_stage)
from simdist.pipelines.twist.recording import (recording_stage)
from simdist.pipelines.twist.chains import (stage_runner, teacher_chain, student_candidates,
                                            candidate_chain, student_chain, pixel_chain,
                                            sac_chain)

__all__ = [
    "TWIST", "STUDENTS", "ASYMMETRIC_SAC", "REFERENCES", "PIXEL_DREAMERS", "Config",
    "PRESETS", "TRAIN_CAMERA_JITTER", "saved_config", "training_visual", "state_dim",
    "twist_config", "READOUT_DIR", "SAC_FIELDS", "BASELINE_FIELDS", "saved_meta",
    "teacher_agent", "records_images", "teacher_stage", "select_teacher", "load_teacher",
    "evaluate", "last_snapshot", "snapshot_teacher", "references_stage", "new_student",
    "build_student", "train_student", "deploy_student", "student_stage", "readout_file",
    "new_readout_student", "mask_runs", "with_readings", "recorded_images",
    "with_positions", "readout_positions", "readout_training_runs", "ExactPositions",
    "validate_student", "candidate_student_stage", "select_student",
    "selected_student_stage", "pixel_dreamer_stage", "asymmetric_sac_stage",
    "recording_stage", "stage_runner", "teacher_chain", "student_candidates",
    "candidate_chain", "student_chain", "pixel_chain", "sac_chain",
]
