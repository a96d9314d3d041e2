"""Ship a finished run's pretrained world model as the package's ``simdist/quadruped``.

The shipped agent (:data:`simdist.pretrained.PRETRAINED`) is the ``agent.pt`` the
recipe's pretraining stage writes (weights, sizes and planner settings in one
weights-only file), copied beside a ``training_record.json`` that says how it was made:
the run's whole config, the command that reproduces it, the machine, each stage's wall
time, the pretraining loss curve and, if the run got that far, its zero-shot figures.

Usage (after ``python recipes/simdist_quadruped.py --output-dir runs/default``, or with
that run's pretraining stage finished)::

    python -m simdist.pipelines.simdist.shipping runs/default
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

from simdist.agents import SimDistAgent
from simdist.pipelines.experiment_log import read_csv_scalars
from simdist.pretrained import PRETRAINED, checkpoints_folder
from simdist.utils import write_json_atomic
from simdist.utils.machine import describe_machine
from simdist.utils.stages import read_json, read_stage_record

NAME = "simdist/quadruped"
#: Points of each loss curve kept in the record (every k-th update).
CURVE_POINTS = 100


def zero_shot_summary(result: dict) -> dict:
    """Each domain's progress (mean, IQM, 95% CI as fractions of the commanded distance)."""
    keys = ("mean_fraction", "iqm_fraction", "ci_fraction", "std_fraction")
    return {domain: {k: r[k] for k in keys if k in r} for domain, r in result.items()}


def training_record(run: str | Path) -> dict:
    """What :func:`ship` writes beside the agent, read from the run folder ``run``."""
    run = Path(run)
    config = read_json(run / "config.json", "run config")
    timings = {}
    for stage in ("expert", "expert_zero_shot", "dataset", "pretrain", "zero_shot"):
        if (run / "stages" / f"{stage}.json").exists():
            timings[stage] = read_stage_record(run, stage)["seconds"]
    pretrain = read_stage_record(run, "pretrain")["result"]
    dataset = read_stage_record(run, "dataset")["result"]
    scalars = read_csv_scalars(run / "logs") if (run / "logs").exists() else {}
    curve = {}
    for key, (steps, values) in scalars.items():
        if key.startswith("pretrain/loss_"):
            every = max(1, len(steps) // CURVE_POINTS)
            curve[key.split("/", 1)[1]] = {"update": steps[::every], "value": values[::every]}
    results = run / "results.json"
    machine = (json.loads(results.read_text()).get("machine") if results.exists()
               else describe_machine(measure=False))
    record = {
        "name": NAME,
        "command": ("python recipes/simdist_quadruped.py --output-dir RUN --seed "
                    f"{config['seed']} && python -m simdist.pipelines.simdist.shipping RUN"),
        "config": config, "machine": machine, "stage_seconds": timings,
        "dataset": {k: dataset[k] for k in ("transitions", "noised_fraction") if k in dataset},
        "pretrain": {k: pretrain[k] for k in ("first", "last", "heldout_prediction_error_rel",
                                              "heldout_prediction_copy_rel")
                     if k in pretrain},
        "loss_curve": curve,
    }
    if (run / "stages" / "zero_shot.json").exists():
        record["zero_shot"] = zero_shot_summary(read_stage_record(run, "zero_shot")["result"])
    return record


def ship(run: str | Path, dest: str | Path | None = None) -> Path:
    """Copies ``run``'s pretrained agent and writes its training record; returns the agent
    file's new path. The agent is loaded first, so a broken file is never shipped."""
    entry = PRETRAINED[NAME]
    dest_file = Path(dest) / Path(entry.file).name if dest else checkpoints_folder() / entry.file
    agent_file = Path(read_stage_record(run, "pretrain")["result"]["agent"])
    SimDistAgent.load(agent_file)  # refuses a corrupt or incompatible file, naming it
    dest_file.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(agent_file, dest_file)
    write_json_atomic(dest_file.parent / Path(entry.record).name, training_record(run))
    return dest_file


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m simdist.pipelines.simdist.shipping",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("run", help="a SimDist run folder whose pretraining has finished")
    parser.add_argument("--dest", default=None,
                        help="folder to write to (default: the package's checkpoints)")
    args = parser.parse_args(argv)
    print(f"shipped {ship(args.run, args.dest)}")


if __name__ == "__main__":
    main()
