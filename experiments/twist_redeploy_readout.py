"""Deploy a finished TWIST run's students through another readout (issue 19; not a speed
benchmark).

The recipe's readout student (``recipes/twist_dmc.py``, ``student_readout``) trains on D's
exact positions by default, so the frozen readout in front of it matters only when it is
deployed from pixels. This script re-deploys the selected student of each seed of a
finished run with the readout of ``--readout`` in place of the one it was saved with, and
evaluates it exactly as the recipe's selection stage does (``twist_dmc.evaluate``: the
held-out scenes of seed ``seed + 10000``), beside the run's own figure. With the same
student weights and evaluation worlds, the difference is the readout's alone.

Usage:
    python experiments/twist_redeploy_readout.py --outputs RUN --seeds 0 1 2 \\
        --readout src/simdist/checkpoints/twist_readout/cartpole-balance.pt --json out.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from simdist.modules import StateReadout
from simdist.pipelines import twist as recipe
from simdist.utils import load_checkpoint
from simdist.utils.stages import read_stage_record

_READOUT = "encoder.readout."


def redeploy(cfg: recipe.Config, task: str, seed: int, outputs: Path,
             readout: StateReadout, student: str = "twist") -> dict:
    """The run's selected ``student`` of ``seed`` with ``readout`` in front, evaluated from
    pixels on the recipe's held-out scenes; with the run's own figure."""
    stage = outputs / "stages" / f"{task}_s{seed}_{student}.json"
    if not stage.exists():
        raise FileNotFoundError(f"no finished student stage {stage}")
    result = read_stage_record(outputs, stage.stem)["result"]
    teacher_file = outputs / "stages" / f"{task}_s{seed}_teacher.json"
    teacher = read_stage_record(outputs, teacher_file.stem)["result"]
    teacher = {**teacher, "agent": result.get("teacher_agent", teacher["agent"])}
    torch.manual_seed(seed)
    twist = recipe.new_readout_student(cfg, task, recipe.load_teacher(cfg, task, teacher),
                                       readout, recipe.STUDENTS[student][1])
    saved = load_checkpoint(result["checkpoint"])["state"]["twist"]["student"]
    # the student's own weights; the readout's are the new one's
    weights = {k: v for k, v in saved.items() if not k.startswith(_READOUT)}
    weights.update({_READOUT + k: v for k, v in readout.state_dict().items()})
    twist.student.load_state_dict(weights)
    start = time.perf_counter()
    stats = recipe.evaluate(cfg, task, seed, twist.policy(), twist.make_primer(), pixels=True)
    return {"seed": seed, "student": student, "chosen": result.get("chosen"),
            "run_mean": result["mean"], "run_returns": result["returns"],
            "mean": stats["mean"], "std": stats["std"], "returns": stats["returns"],
            "seconds": round(time.perf_counter() - start, 1)}


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--outputs", type=Path, required=True, help="a finished recipe run")
    parser.add_argument("--seeds", type=int, nargs="+", required=True)
    parser.add_argument("--readout", type=Path, required=True, help="a StateReadout file")
    parser.add_argument("--task", default="cartpole-balance")
    parser.add_argument("--student", choices=list(recipe.STUDENTS), default="twist")
    parser.add_argument("--preset", choices=sorted(recipe.PRESETS), default="default",
                        help="used only when --outputs has no config.json")
    parser.add_argument("--json", type=Path, default=None, help="append one line per seed")
    args = parser.parse_args(argv)
    cfg = recipe.saved_config(args.outputs, args.preset)
    readout = StateReadout.load(args.readout)
    rows = []
    for seed in args.seeds:
        rows.append(redeploy(cfg, args.task, seed, args.outputs, readout, args.student))
        print(json.dumps(rows[-1]), flush=True)
        if args.json:
            with args.json.open("a") as f:
                f.write(json.dumps(rows[-1]) + "\n")
    return rows


if __name__ == "__main__":
    main()
