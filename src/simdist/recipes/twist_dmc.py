"""TWIST on the control suite: distil an image student from a state teacher, with baselines.

Per task and seed (each stage checkpointed under ``--output-dir``; rerunning skips
finished stages and a killed stage resumes from its last checkpoint):

1. ``teacher``: Dreamer on privileged state, collecting online; every step also records
   the domain-randomised image (randomised every step), building ``D = {(s, o, a, r)}``.
2. ``oracle``: the teacher itself, evaluated (the upper bound); ``references``: zero and
   uniform random actions on the same seeds, what a return is worth on the task (doing
   nothing scores 750 on cartpole-balance, where the pole swings back past upright).
3. ``twist`` and its ablations (``no_imagined``, ``no_noise``): an image RSSM with a CNN
   encoder, trained with the teacher frozen on slices of ``D`` by latent distillation
   (Eq. 3) plus imagined-rollout alignment (Eq. 4) alone; deployed as pixels -> student
   latent -> the teacher's actor. ``--student-readout auto`` trains the readout student
   instead where a task has a committed readout (cartpole-balance): a frozen CNN fitted by
   privileged state regression, another method than TWIST, reported under its own name
   (docs/methods.md, section 2.7).
4. ``dreamer_dr`` / ``dreamer_no_dr``: Dreamer from pixels, with and without visual DR,
   with the same environment-step budget as the teacher (at the CPU default with fewer
   updates: a pixel update costs ~4x a state update; ``paper`` gives all the same ratio).
   ``dreamer_state_recon``: TWIST's "Dreamer State Recon." baseline, a pixel Dreamer with
   DR whose decoder reconstructs the privileged state instead of the image (same budget).
5. ``asymmetric_sac``: TWIST's model-free baseline, TorchRL SAC with a pixel actor and a
   privileged-state critic, trained online with DR for the same environment steps.

Every method is evaluated on **held-out** textures (train colours, camera jitter; drawn
once per episode), on the same seeds.

The stages that need the teacher (teacher, oracle, students) form one chain; each pixel
Dreamer is a chain of its own. ``--jobs 2`` (the default on two or more cores) runs the
chains side by side in two processes, one torch thread each.

The stages themselves live in :mod:`simdist.pipelines.twist`, one module per concern;
this file is their order and the table.

Usage:
    python recipes/twist_dmc.py                    # cartpole-balance: ~45 min per seed
    python recipes/twist_dmc.py --preset tiny      # seconds, used by the tests
    python recipes/twist_dmc.py --preset paper --device cuda   # six tasks x 3 seeds, 500K steps
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import simdist  # noqa: F401  (headless GL set-up before dm_control)
from simdist.pipelines.experiment_log import plot_curves
from simdist.pipelines.twist.chains import (_stage, candidate_chain, pixel_chain, sac_chain,
                                            stage_runner, student_candidates, student_chain,
                                            teacher_chain)
from simdist.pipelines.twist.config import (ASYMMETRIC_SAC, PIXEL_DREAMERS, PRESETS, REFERENCES,
                                            Config)
from simdist.pipelines.twist.readout import student_row
from simdist.pipelines.twist.recording import recording_stage
from simdist.pipelines.twist_report import ORACLE, format_table, plot_results, summarise
from simdist.utils import run_jobs
from simdist.utils.sealed import write_run_json
from simdist.utils.cli import exit_on_folder_errors, parse_config
from simdist.utils.machine import describe_machine, machine_line


def main(argv=None):
    cfg, _ = parse_config(Config, PRESETS, argv, description=__doc__.splitlines()[0],
                          prog="twist_dmc.py")
    out = Path(cfg.output_dir)
    with exit_on_folder_errors("twist_dmc.py"):  # another config's folder: before any work
        runner = stage_runner(cfg)

    # Teachers first (everything of TWIST waits for them), then each teacher's students,
    # which start as soon as their teacher is done, ahead of the baselines still queued.
    chains = [(teacher_chain, (cfg, task, seed)) for task in cfg.tasks for seed in cfg.seeds]
    after = [()] * len(chains)
    for i, (task, seed) in enumerate((t, s) for t in cfg.tasks for s in cfg.seeds):
        for suffix in cfg.students:  # candidates (if any) side by side, then the choice
            first = len(chains)
            for name in student_candidates(cfg, task):
                chains.append((candidate_chain, (cfg, task, seed, suffix, name)))
                after.append((i,))
            after.append(tuple(range(first, len(chains))) or (i,))
            chains.append((student_chain, (cfg, task, seed, suffix)))
    stages = {}  # stage suffix -> table row (a student's depends on the task: readout_file)
    if cfg.baselines:
        chains += [(pixel_chain, (cfg, task, seed, suffix)) for task in cfg.tasks
                   for seed in cfg.seeds for suffix in PIXEL_DREAMERS]
        chains += [(sac_chain, (cfg, task, seed)) for task in cfg.tasks for seed in cfg.seeds]
        after += [()] * (len(chains) - len(after))
        stages.update({suffix: name for suffix, (name, _) in PIXEL_DREAMERS.items()})
        stages[ASYMMETRIC_SAC[0]] = ASYMMETRIC_SAC[1]
    start = time.perf_counter()
    machine = describe_machine()  # timings in results.json mean little without it
    print("machine: " + machine_line(machine))
    run_jobs(chains, cfg.jobs, after=after)

    results, records = {}, {}
    for task in cfg.tasks:
        methods = {}
        for seed in cfg.seeds:
            key = f"{task}_s{seed}"
            teacher = runner.result(f"{key}_teacher")
            runs = {ORACLE: runner.result(f"{key}_oracle")}
            for suffix in cfg.students:
                runs[student_row(cfg, task, suffix)] = runner.result(f"{key}_{suffix}")
            for suffix, name in stages.items():
                runs[name] = runner.result(f"{key}_{suffix}")
            references = runner.result(f"{key}_references")
            for kind, name in REFERENCES.items():
                runs[name] = references[kind]
            records[key] = {"teacher": teacher, **runs}
            for name, r in runs.items():
                entry = methods.setdefault(name, {"returns": [], "seed_means": [],
                                                  "seed_returns": []})
                entry["returns"] += r["returns"]
                entry["seed_means"].append(r["mean"])
                entry["seed_returns"].append(r["returns"])
        results[task] = methods

    recording = None
    if cfg.record:
        task, seed = cfg.tasks[0], cfg.seeds[0]
        # the TWIST student's own teacher (a candidate may come from another snapshot)
        teacher = records[f"{task}_s{seed}"]["teacher"]
        teacher = {**teacher, "agent": runner.result(f"{task}_s{seed}_twist").get(
            "teacher_agent", teacher["agent"])}
        recording = _stage(runner, "recording", lambda d: recording_stage(
            cfg, task, seed, teacher, out))
    wall = time.perf_counter() - start
    print("\n" + format_table(results))
    no_dr = PIXEL_DREAMERS["dreamer_no_dr"][0]
    for key, runs in records.items():  # the no-DR baseline on held-out scenes says little
        own = runs.get(no_dr, {}).get("own_scene")
        if own:  # absent from stages run before it was measured
            print(f"{key}: {no_dr} on its own training scene {own['mean']:.1f} +- "
                  f"{own['std']:.1f} (held-out scenes: {runs[no_dr]['mean']:.1f})")
    print("\nstage timings: " + ", ".join(f"{k} {v:.0f} s" for k, v in runner.timings.items()))
    print(f"wall time this run: {wall:.0f} s with {cfg.jobs} process(es)")
    write_run_json(out / "results.json",  # a crash mid-write keeps the previous file
        {"config": dataclasses.asdict(cfg), "results": results, "summary": summarise(results),
         "runs": records, "recording": recording, "timings_s": runner.timings,
         "wall_s": wall, "jobs": cfg.jobs, "machine": machine}, out)
    plot_results(results, out / "returns.png")
    print(f"wrote {out / 'results.json'} and {out / 'returns.png'}")
    if cfg.logger == "csv" and plot_curves(out / "logs", out / "training_curves.png"):
        print(f"training curves: {out / 'training_curves.png'} (scalars in {out / 'logs'})")
    if recording:
        print(f"rerun recording (open with `rerun FILE`): {recording['path']}")


def cli() -> None:
    """The ``simdist-twist`` console script: :func:`main` on ``sys.argv``, exit status 0."""
    main()


if __name__ == "__main__":
    main()
