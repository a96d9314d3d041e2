"""Ship a TWIST run's teacher and student for one task as named pretrained agents.

Copies ``<task>_s<seed>_teacher/teacher_agent.pt`` (the state Dreamer, the Oracle) and
``<task>_s<seed>_twist/student_agent.pt`` (the image student) into the package's
``checkpoints/twist_<task>/``, with a ``training_record.json``: the run's config, the
command, the machine, the teacher's updates and episode returns, and the held-out
returns of the Oracle, the student and the zero / random-action references, so whoever
loads them knows what they are worth.

Usage::

    python recipes/twist_dmc.py --tasks cartpole-balance --seeds 0 --students twist \\
        --no-baselines --output-dir RUN
    python -m simdist.pipelines.twist.shipping RUN --task cartpole-balance --seed 0
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

from simdist.agents import load_agent
from simdist.pretrained import checkpoints_folder
from simdist.utils import write_json_atomic
from simdist.utils.machine import describe_machine
from simdist.utils.stages import read_json, read_stage_record


def _returns(result: dict) -> dict:
    return {k: result[k] for k in ("mean", "std", "returns") if k in result}


def training_record(run: str | Path, task: str, seed: int) -> dict:
    """What :func:`ship` writes beside the two agents."""
    run, key = Path(run), f"{task}_s{seed}"
    teacher = read_stage_record(run, f"{key}_teacher")
    student = read_stage_record(run, f"{key}_twist")
    record = {
        "task": task, "seed": seed,
        "command": (f"python recipes/twist_dmc.py --tasks {task} --seeds {seed} --students "
                    "twist --no-baselines --output-dir RUN && python -m "
                    f"simdist.pipelines.twist.shipping RUN --task {task} --seed {seed}"),
        "config": read_json(run / "config.json", "run config"),
        "machine": (json.loads((run / "results.json").read_text()).get("machine")
                    if (run / "results.json").exists() else describe_machine(measure=False)),
        "teacher": {"updates": teacher["result"].get("updates"),
                    "episode_returns": teacher["result"].get("episode_returns"),
                    "seconds": teacher["seconds"]},
        "student": {"updates": student["result"].get("updates"),
                    "student": student["result"].get("student"), "seconds": student["seconds"],
                    "held_out": _returns(student["result"])},
    }
    if (run / "stages" / f"{key}_oracle.json").exists():
        record["oracle_held_out"] = _returns(read_stage_record(run, f"{key}_oracle")["result"])
    if (run / "stages" / f"{key}_references.json").exists():
        refs = read_stage_record(run, f"{key}_references")["result"]
        record["references_held_out"] = {k: _returns(v) for k, v in refs.items()}
    return record


def ship(run: str | Path, task: str, seed: int = 0, dest: str | Path | None = None) -> Path:
    """Copies the teacher and student agent files (each loaded first: a broken file is
    never shipped) and writes the record; returns the folder."""
    key = f"{task}_s{seed}"
    folder = Path(dest) if dest else checkpoints_folder() / f"twist_{task}"
    files = {"teacher.pt": read_stage_record(run, f"{key}_teacher")["result"]["agent"],
             "student.pt": read_stage_record(run, f"{key}_twist")["result"]["agent"]}
    for source in files.values():
        load_agent(source)  # refuses a corrupt or incompatible file, naming it
    folder.mkdir(parents=True, exist_ok=True)
    for name, source in files.items():
        shutil.copyfile(source, folder / name)
    write_json_atomic(folder / "training_record.json", training_record(run, task, seed))
    return folder


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m simdist.pipelines.twist.shipping",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("run", help="a TWIST run folder whose teacher and student finished")
    parser.add_argument("--task", required=True, help="the task to ship, e.g. cartpole-balance")
    parser.add_argument("--seed", type=int, default=0, help="the run's seed to ship")
    parser.add_argument("--dest", default=None,
                        help="folder to write to (default: the package's checkpoints)")
    args = parser.parse_args(argv)
    print(f"shipped {ship(args.run, args.task, args.seed, args.dest)}")


if __name__ == "__main__":
    main()
