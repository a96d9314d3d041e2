"""SimDist on the quadruped: pretrain in simulation, plan, finetune dynamics on target data.

Stages (each checkpointed under ``--output-dir``; rerunning skips finished stages and a
killed stage resumes from its last checkpoint):

1. ``expert``: load the committed state-based SAC expert (or retrain it on request);
   ``expert_zero_shot`` measures its transfer to every named domain.
2. ``dataset``: a perturbed-expert dataset on disk (mixture of final and earlier
   policies, SimDist's burst/pause action noise, expert-critic value labels) on mixed
   terrain (``data_task``: slopes of -15..15 degrees under the training dynamics
   randomisation), so the geometry of every target is in distribution and only its
   dynamics shift (friction, softness, motors, latency, payload) is not.
3. ``pretrain``: the SimDist world model (history encoder on robot-measurable
   observations only, latent dynamics, reward, value, policy prior) on that dataset.
4. ``zero_shot``: latent MPPI with the pretrained model, in simulation and in the target;
   ``frozen_parts``: the policy prior alone and (``--ceiling-episodes``) the planner with
   the simulator as its dynamics, in the target: what the frozen parts allow.
5. ``round_k``: collect target data with the current planner, then finetune **only the
   dynamics** (SimDist) and evaluate; the same data also finetunes the whole world model
   (ablation) and continues the expert's SAC (policy-finetuning baseline).

The stages themselves live in :mod:`simdist.pipelines.simdist`, one module per concern;
this file is their order.

Usage:
    python recipes/simdist_quadruped.py                  # small CPU default (~30 min)
    python recipes/simdist_quadruped.py --preset tiny    # seconds, used by the tests
    python recipes/simdist_quadruped.py --target foam --episodes 9
    python recipes/simdist_quadruped.py --preset paper --device cuda  # reference scales
    python recipes/simdist_quadruped.py --retrain-expert # hours on 2 CPU cores
"""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import torch

import simdist  # noqa: F401  (headless GL set-up before dm_control)
from simdist.envs import describe_ranges, get_target
from simdist.experts import Expert, resolve_expert
from simdist.pipelines.experiment_log import make_logger, plot_curves
from simdist.pipelines.report import aggregate_seeds, plot_results, print_table
from simdist.pipelines.simdist.config import PRESETS, SIMDIST, Config
from simdist.pipelines.simdist.evaluation import (collect_results, expert_zero_shot_stage,
                                                  zero_shot_job)
from simdist.pipelines.simdist.expert_data import dataset_stage, expert_stage
from simdist.pipelines.simdist.frozen_parts import frozen_parts_stage
from simdist.pipelines.simdist.jobs import stage_jobs
from simdist.pipelines.simdist.pretraining import pretrain_stage
from simdist.pipelines.simdist.recording import probe_stage, recording_stage
from simdist.pipelines.simdist.rounds import round_stage
from simdist.utils import RunFolderError, StageRunner, run_jobs
from simdist.utils.sealed import write_run_json
from simdist.utils.checkpoint import CorruptCheckpointError
from simdist.utils.cli import exit_on_folder_errors, parse_config, usage_error
from simdist.utils.machine import describe_machine, machine_line
from simdist.utils.precision import resolve_precision
from simdist.viz.video import INSTALL_HINT, video_backend_available


def run(cfg: Config) -> dict:
    """Every stage of one seed into ``cfg.output_dir``; returns the results it wrote."""
    out = Path(cfg.output_dir)
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    # finished stages are skipped when rerun; device, threads, dataset workers and whether
    # to record may differ from the first run's
    runner = StageRunner(out, dataclasses.replace(cfg, seeds=[]),
                         runtime_keys=("device", "logger", "threads", "dataset_workers",
                                       "record", "ensemble_jobs", "jobs"))
    logger = make_logger(cfg.logger, out)
    precision = {name: resolve_precision(getattr(cfg, name), cfg.device)
                 for name in ("mixed_precision", "planner_precision")}
    print(f"precision on {cfg.device}: training {precision['mixed_precision']}, planning "
          f"{precision['planner_precision']} (none = float32)")
    machine = describe_machine()  # timings in results.json mean little without it
    print("machine: " + machine_line(machine))
    print("Training randomisation vs target domains:\n" + describe_ranges() + "\n")
    if cfg.record and not video_backend_available():  # say so now, not after the training
        warnings.warn(f"the recordings stage will write rerun files without MP4 videos: "
                      f"{INSTALL_HINT}", stacklevel=2)

    def stage(name, fn):
        if runner.done(name):
            print(f"stage {name}: already done, reusing its results")
        return runner.run(name, fn)

    expert = stage("expert", lambda d: expert_stage(cfg, d))
    # a record copied from results/ names the shipped expert relative to the repository
    # root (checkpoints/quadruped_expert/expert.pt), which only resolve_expert finds from
    # any working directory
    expert = {**expert, "path": str(resolve_expert(expert["path"]))}
    expert_zero_shot = stage("expert_zero_shot",
                             lambda d: expert_zero_shot_stage(cfg, expert["path"]))
    missing = [t for t in cfg.expert_targets if t not in expert_zero_shot]
    if missing:  # e.g. a record copied in from a run with other targets
        raise RunFolderError(f"{out / 'stages' / 'expert_zero_shot.json'} has no result for "
                         f"{missing} (it holds {sorted(expert_zero_shot)}); delete it to "
                         "re-evaluate the expert on every target of this config")
    dataset = stage("dataset", lambda d: dataset_stage(cfg, expert["path"], d))
    pretrained = stage("pretrain", lambda d: pretrain_stage(cfg, dataset["path"],
                                                            expert["path"], d, logger))
    print("pretraining: loss-term shares (last updates) "
          + ", ".join(f"{k[5:]} {100 * v:.0f}%" for k, v in pretrained["term_shares_last"].items())
          + "; held-out latent prediction error / latent variance at steps 1..H: "
          + ", ".join(f"{e:.2f}" for e in pretrained["heldout_prediction_error_rel"])
          + (" (predicting no change: "
             + ", ".join(f"{e:.2f}" for e in pretrained["heldout_prediction_copy_rel"]) + ")"
             if "heldout_prediction_copy_rel" in pretrained else ""))

    check_weights_for_stages(cfg, runner, pretrained)

    def zero_shot(d):
        domains = ["sim", cfg.target]
        jobs, threads = stage_jobs(cfg, len(domains))
        return dict(zip(domains, run_jobs([(zero_shot_job, (cfg, pretrained, domain))
                                           for domain in domains], jobs, threads=threads)))

    planner_zero_shot = stage("zero_shot", zero_shot)
    frozen_parts = stage("frozen_parts", lambda d: frozen_parts_stage(cfg, pretrained))
    probe = (stage("probe", lambda d: probe_stage(cfg, dataset["path"], pretrained, d, logger))
             if cfg.record else None)
    rounds, previous = [], None
    for k in range(len(cfg.budgets_min)):
        previous = stage(f"round_{k + 1}", lambda d, k=k, p=previous: round_stage(
            cfg, k, pretrained, expert["path"], d, p, logger, dataset["path"]))
        rounds.append(previous)

    recordings = (stage("recordings",
                        lambda d: recording_stage(cfg, pretrained, probe, rounds[-1], out))
                  if cfg.record else {})
    results = collect_results(cfg, expert_zero_shot, planner_zero_shot, rounds, frozen_parts)
    runner.close()
    print_table(results, get_target(cfg.target).name, reference=SIMDIST)
    print("\nstage timings: " + ", ".join(f"{k} {v:.0f} s" for k, v in runner.timings.items()))
    summary = {"config": dataclasses.asdict(cfg), "expert": expert, "dataset": dataset,
               "pretrain": pretrained, "expert_zero_shot": expert_zero_shot,
               "planner_zero_shot": planner_zero_shot, "frozen_parts": frozen_parts,
               "probe": probe,
               "recordings": recordings, "curves": results, "timings_s": runner.timings,
               "torch_threads": torch.get_num_threads(), "precision": precision,
               "machine": machine}
    write_run_json(out / "results.json", summary, out)
    plot_results(results, get_target(cfg.target).name, out / "forward_progress.png")
    print(f"wrote {out / 'results.json'} and {out / 'forward_progress.png'}")
    if cfg.logger == "csv" and plot_curves(out / "logs", out / "training_curves.png"):
        print(f"training curves: {out / 'training_curves.png'} (scalars in {out / 'logs'})")
    if recordings:
        print("rerun recordings (open with `rerun FILE`) and videos: "
              + ", ".join(recordings.values()))
    return summary


def check_weights_for_stages(cfg: Config, runner: StageRunner, pretrained: dict) -> None:
    """Refuses, by name, a folder whose pretraining is a record without its weights (e.g.
    a copy made by ``python -m simdist.utils.records``) when a stage still to run needs
    them, instead of failing inside that stage."""
    later = ["zero_shot", "frozen_parts",
             *(f"round_{k + 1}" for k in range(len(cfg.budgets_min)))]
    to_run = [name for name in later + (["probe", "recordings"] if cfg.record else [])
              if not runner.done(name)]
    if not to_run or Path(pretrained["path"]).exists():
        return
    how = ("pass --no-record to rebuild the tables from the records alone"
           if set(to_run) <= {"probe", "recordings"} else
           "use another --output-dir, or delete its stages/pretrain.json to pretrain again")
    raise RunFolderError(f"{runner.out} holds the pretraining's record but not its weights "
                         f"({pretrained['path']}), which stages {to_run} need: {how}")


def run_seeds(cfg: Config) -> dict:
    """Each of ``cfg.seeds`` into ``<output_dir>/seed_<N>``, then one aggregated table."""
    out = Path(cfg.output_dir)
    per_seed = [run(dataclasses.replace(cfg, seed=s, seeds=[], output_dir=str(out / f"seed_{s}")))
                for s in cfg.seeds]
    curves = aggregate_seeds([r["curves"] for r in per_seed])
    print(f"\n{len(cfg.seeds)} seeds {cfg.seeds} (statistics over all their episodes; "
          "'seeds' gives each seed's mean)")
    print_table(curves, get_target(cfg.target).name, reference=SIMDIST)
    summary = {"config": dataclasses.asdict(cfg), "seeds": cfg.seeds, "curves": curves,
               "per_seed": {str(s): str(out / f"seed_{s}" / "results.json") for s in cfg.seeds}}
    write_run_json(out / "results.json", summary, out)
    plot_results(curves, get_target(cfg.target).name, out / "forward_progress.png")
    print(f"wrote {out / 'results.json'} and {out / 'forward_progress.png'}")
    return summary


def main(argv=None):
    cfg, _ = parse_config(Config, PRESETS, argv, description=__doc__.splitlines()[0],
                          prog="simdist_quadruped.py")
    if not cfg.retrain_expert:  # a missing or bad expert is refused before any work
        path = resolve_expert(cfg.expert)
        if not path.exists():
            usage_error("simdist_quadruped.py", f"expert: no checkpoint at {cfg.expert}: "
                        "train one with `python recipes/train_expert.py` or pass "
                        "--retrain-expert")
        try:
            Expert.load(path)
        except (CorruptCheckpointError, OSError) as err:
            usage_error("simdist_quadruped.py", f"expert: {err}")
    with exit_on_folder_errors("simdist_quadruped.py"):
        return run_seeds(cfg) if cfg.seeds else run(cfg)


def cli() -> None:
    """The ``simdist-quadruped`` console script: :func:`main` on ``sys.argv``, exit status 0."""
    main()


if __name__ == "__main__":
    main()
