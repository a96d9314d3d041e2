"""How many environment steps does the TWIST state teacher need? (not a speed benchmark)

Trains the recipe's state teacher (``recipes/twist_dmc.py``: the same ``DreamerConfig``,
``OnlineConfig`` and seeding) on privileged state, *without* rendering images (the
images of ``D`` do not change what the teacher learns, and rendering is the slow part on
CPU), and evaluates it as the recipe's ``oracle`` stage does (deterministic actor, the
recipe's evaluation seeds) after every ``--chunk`` agent steps. Beside it, the two blind
references of the recipe's ``references`` stage (zero and uniform random actions): on
cartpole-balance doing nothing scores ~750, so a teacher below that has not learned to
balance, and percentages of its return say little.

The run resumes: rerunning with a larger ``--steps`` into the same ``--out`` continues
from the stored episodes and checkpoint.

Usage:
    python experiments/twist_teacher_budget.py --seeds 0 1 --steps 10000 --chunk 2000
    python experiments/twist_teacher_budget.py --task cheetah-run --seeds 0 --steps 6000
    python experiments/twist_teacher_budget.py --seeds 0 1 --return-normalisation percentile
    python experiments/twist_teacher_budget.py --seeds 0 --steps 12000 --standardise
    python experiments/twist_teacher_budget.py --preset tiny --steps 40 --chunk 20  # the test
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import torch

from simdist.agents.dreamer import RETURN_NORMALISATIONS
from simdist.pipelines import (control_env, dreamer_keys, stage_seed,
                               train_dreamer_online)
from simdist.pipelines import twist as recipe


def variant(cfg: recipe.Config) -> str:
    """What the run's folder and result file add to the task's name: the return scaling
    and the standardised state target, when not the default."""
    return ("" if cfg.return_normalisation == "none" else
            f"_return_{cfg.return_normalisation}") + ("_standardised" if cfg.teacher_standardise
                                                     else "")


def teacher_curve(cfg: recipe.Config, task: str, seed: int, steps: int, chunk: int,
                  out: Path) -> list[dict]:
    """The Oracle's held-out-seed return after every ``chunk`` steps up to ``steps``."""
    torch.manual_seed(seed)
    agent = recipe.teacher_agent(cfg, task)
    env = control_env(task, seed, max_episode_steps=cfg.episode_steps,
                      primer=agent.make_primer())
    curve = []
    try:
        for budget in range(chunk, steps + 1, chunk):
            start = time.perf_counter()
            online = dataclasses.replace(cfg, env_steps=budget).online()
            run = train_dreamer_online(agent, env, online,
                                       out / f"{task}_s{seed}{variant(cfg)}",
                                       dreamer_keys("state"), desc=f"teacher {task} s{seed}",
                                       seed=stage_seed(seed, f"{task}/teacher"))
            oracle = recipe.evaluate(cfg, task, seed, agent.policy(explore=False),
                                     agent.make_primer(), pixels=False)
            curve.append({"steps": budget, "updates": run["updates"],
                          "oracle_mean": oracle["mean"], "oracle_std": oracle["std"],
                          "oracle_returns": oracle["returns"],
                          "last_training_returns": run["episode_returns"][-2:],
                          "seconds": time.perf_counter() - start})
            print(json.dumps(curve[-1]), flush=True)
    finally:
        env.close()
    return curve


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="cartpole-balance")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--steps", type=int, default=10000, help="largest budget")
    parser.add_argument("--chunk", type=int, default=2000, help="evaluate every this many")
    parser.add_argument("--out", default="outputs/twist_teacher_budget")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--preset", default="default", choices=sorted(recipe.PRESETS),
                        help="the recipe preset whose teacher settings to use")
    parser.add_argument("--return-normalisation", choices=RETURN_NORMALISATIONS,
                        help="the actor's returns as they come or divided by their running "
                             "percentile range, DreamerV3's (default: the preset's)")
    parser.add_argument("--standardise", action="store_true",
                        help="the teacher reconstructs its state standardised per dimension "
                             "(the recipe's teacher_standardise)")
    args = parser.parse_args(argv)
    if args.chunk < 1 or args.steps < args.chunk:
        parser.error("need 1 <= --chunk <= --steps")
    torch.set_num_threads(args.threads)
    # the curve of the last weights at each budget: no snapshot selection
    cfg = recipe.Config(**{**recipe.PRESETS[args.preset], "tasks": [args.task],
                           "seeds": args.seeds, "teacher_snapshots": 0})
    if args.return_normalisation is not None:
        cfg = dataclasses.replace(cfg, return_normalisation=args.return_normalisation)
    cfg = dataclasses.replace(cfg, teacher_standardise=args.standardise)
    out = Path(args.out)
    results = {"references": {}, "curves": {}}
    for seed in args.seeds:
        references = recipe.references_stage(cfg, args.task, seed)
        results["references"][seed] = {kind: r["mean"] for kind, r in references.items()}
        print(f"seed {seed} references: {results['references'][seed]}", flush=True)
        results["curves"][seed] = teacher_curve(cfg, args.task, seed, args.steps, args.chunk,
                                                out)
    print("\nsteps  " + "  ".join(f"seed {s:>3}" for s in args.seeds))
    for i, budget in enumerate(range(args.chunk, args.steps + 1, args.chunk)):
        print(f"{budget:>5}  " + "  ".join(f"{results['curves'][s][i]['oracle_mean']:8.0f}"
                                          for s in args.seeds))
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{args.task}{variant(cfg)}.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
