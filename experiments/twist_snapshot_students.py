"""Which of a teacher's snapshots distils best? (not a speed benchmark)

The TWIST recipe (``recipes/twist_dmc.py``) keeps the teacher's weights after each of its
last ``teacher_snapshots`` training episodes and deploys the one with the best validated
return. This script distils one readout student from *each* of those snapshots of a
finished run, on the same D, with the recipe's own candidate stage
(``twist_dmc.candidate_student_stage``: the run's student settings, trained on
``--states`` of D), and prints each student's validation return (exact positions on the
recipe's student-validation seeds) beside the snapshot's own. It answers whether the
snapshot that acts best is also the one a student learns best from (it was not on one
fresh seed: docs/findings.md, "Which snapshot to distil from").

Each student is a stage folder of its own under ``--work`` (resumable); ~5 min per
student on one CPU core at the default preset.

Usage:
    python experiments/twist_snapshot_students.py --outputs RUN --seed 5 --snapshots 00014 00023
    python experiments/twist_snapshot_students.py --outputs RUN --seed 0 --preset tiny  # the test
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import torch

from simdist.pipelines import twist as recipe
from simdist.utils.stages import read_stage_record


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--outputs", type=Path, required=True, help="a finished recipe run")
    parser.add_argument("--task", default="cartpole-balance")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--snapshots", nargs="*", default=None,
                        help="snapshot names (e.g. 00014); default: every validated one")
    parser.add_argument("--states", choices=["all", "domain"], default="all",
                        help="which of D's steps each student trains on")
    parser.add_argument("--student", choices=list(recipe.STUDENTS), default="twist")
    parser.add_argument("--preset", choices=sorted(recipe.PRESETS), default="default",
                        help="used only when --outputs has no config.json")
    parser.add_argument("--work", type=Path, default=Path("outputs/twist_snapshot_students"))
    args = parser.parse_args(argv)
    cfg = dataclasses.replace(recipe.saved_config(args.outputs, args.preset),
                              output_dir=str(args.work), jobs=1)
    if recipe.readout_file(cfg, args.task) is None:
        raise SystemExit(f"{args.task} has no readout student under this config: the "
                         "snapshot students are readout students")
    key = f"{args.task}_s{args.seed}"
    result_file = args.outputs / "stages" / f"{key}_teacher.json"
    if not result_file.exists():
        raise SystemExit(f"no finished teacher stage {result_file}")
    teacher = read_stage_record(args.outputs, result_file.stem)["result"]
    if not teacher.get("selection"):
        raise SystemExit(f"the teacher stage of {key} kept no snapshots (teacher_snapshots=0)")
    own = {Path(c["snapshot"]).stem: c for c in teacher["selection"]["candidates"]}
    names = args.snapshots if args.snapshots else list(own)
    unknown = [n for n in names if n not in own]
    if unknown:
        raise SystemExit(f"unknown snapshots {unknown}; validated ones: {list(own)}")
    rows = []
    for name in names:
        stage = args.work / f"{key}_{args.student}_snapshot_{name}"
        start = time.perf_counter()
        snapped = recipe.snapshot_teacher(cfg, args.task, args.seed, teacher,
                                          own[name]["snapshot"], stage)
        torch.manual_seed(args.seed)
        result = recipe.candidate_student_stage(cfg, args.task, args.seed, snapped,
                                                recipe.STUDENTS[args.student][1], args.states,
                                                stage)
        rows.append({"snapshot": name, "deployed": own[name]["snapshot"] ==
                     teacher["selection"]["chosen"], "teacher_validation": own[name]["mean"],
                     "student_validation": result["validation"]["mean"],
                     "student_validation_std": result["validation"]["std"],
                     "seconds": time.perf_counter() - start})
        print(json.dumps(rows[-1]), flush=True)
    return rows


if __name__ == "__main__":
    main()
