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
4. ``zero_shot``: latent MPPI with the pretrained model, in simulation and in the target.
5. ``round_k``: collect target data with the current planner, then finetune **only the
   dynamics** (SimDist) and evaluate; the same data also finetunes the whole world model
   (ablation) and continues the expert's SAC (policy-finetuning baseline).

Usage:
    python recipes/simdist_quadruped.py                  # small CPU default (~30 min)
    python recipes/simdist_quadruped.py --preset tiny    # seconds, used by the tests
    python recipes/simdist_quadruped.py --target foam --episodes 9
    python recipes/simdist_quadruped.py --preset paper --device cuda  # reference scales
    python recipes/simdist_quadruped.py --retrain-expert # hours on 2 CPU cores
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import simdist  # noqa: F401  (headless GL set-up before dm_control)
import torch
from tensordict import TensorDict
from tqdm import tqdm

from simdist.agents import SimDistAgent, SimDistConfig, action_bounds
from simdist.data import (CoTrainingSlices, DatasetConfig, PerturbationSchedule,
                          generate_dataset, generate_shard, load_dataset)
from simdist.data.dataset import read_dataset_meta
from simdist.data.prioritised_slices import PrioritisedSlices, prioritised_update
from simdist.envs import TASKS, Layout, describe_ranges, get_target, make_env
from simdist.experts import Expert, SACExpertConfig, resolve_expert, train_sac_expert
from simdist.modules import SIMDIST_SIZES, SimDistWorldModel, StateDecoder, WorldModelEnsemble
from simdist.objectives import ProbeLoss
from simdist.objectives.simdist_pretrain import (CONSISTENCY_KINDS, SimDistPretrainLoss,
                                                 latent_prediction_skill)
from simdist.modules.planner import PlannerConfig
from simdist.modules.simdist_model import DYNAMICS_RESIDUALS
from simdist.pipelines import (OfflineSAC, OfflineSACConfig, as_slices, episode_stats,
                               locomotion_env, mean_metrics, rollout, stage_seed,
                               train_resumable)
from simdist.pipelines.experiment_log import LOGGERS, log_metrics, make_logger, plot_curves
from simdist.pipelines.locomotion import UPSIDE_DOWN
from simdist.pipelines.report import aggregate_seeds, plot_results, print_table
from simdist.utils import (RunFolderError, StageRunner, load_checkpoint, load_memmap,
                           resolve_device, run_jobs, save_atomic, save_memmap,
                           write_json_atomic)
from simdist.utils.cli import (check, check_builds, check_positive, exit_on_folder_errors,
                               parse_config)
from simdist.utils.machine import describe_machine, machine_line
from simdist.utils.precision import PRECISIONS, resolve_precision
from simdist.utils.stages import ABSENT_MEANS, field_defaults, read_json
from simdist.viz import record_planning_episode
from simdist.viz.video import INSTALL_HINT, video_backend_available

DEFAULT_EXPERT = "checkpoints/quadruped_expert/expert.pt"
STEPS_PER_MINUTE = 50 * 60  # 50 Hz control
SIMDIST = "SimDist: finetune dynamics"  # the method the paired table compares against
SIMNORM_GROUP = 8  # latent dimensions per SimNorm group when --model-latent-dim resizes it
TARGET_KEYS = ["observation", "action", "is_init", ("next", "observation"),
               ("next", "reward"), ("next", "done"), ("next", "terminated")]
# what the finetuning losses read: the entries target and simulation slices share
FINETUNE_KEYS = ["observation", "action", "is_init", ("next", "reward")]


@dataclass
class Config:
    """Flat recipe config; presets below override fields. Saved as ``config.json``.

    Every field is a command-line flag (``--kebab-case``); a value that cannot work is
    refused before any stage runs (:meth:`__post_init__`).
    """

    task: str = "quadruped-flat"  # evaluation task; a target sets its own slope
    data_task: str = "quadruped-terrain"  # expert retraining and the dataset: mixed slopes
    # deployment target: a name in simdist.envs.TARGETS, a JSON object of TargetDomain
    # fields ('{"name": "icy", "friction": 0.4}') or the path of a .json file holding one
    target: str = "slippery_slope"
    expert: str = DEFAULT_EXPERT  # expert checkpoint (SAC, recipes/train_expert.py)
    retrain_expert: bool = False  # retrain the expert on data_task (hours on 2 CPU cores)
    expert_frames: int = SACExpertConfig.total_frames  # SAC frames when retraining
    # domains the expert is evaluated in zero-shot (the target is added if missing)
    expert_targets: list[str] = field(default_factory=lambda: [
        "sim", "slippery_slope", "foam", "payload", "weak_motors"])
    # evaluation episodes per point (batched worlds): 12 gave CIs of +-40 points
    episodes: int = 32
    episode_steps: int = 250  # 5 s at 50 Hz
    seed: int = 0  # seed of every stage of a single run
    # several seeds: each runs into <output_dir>/seed_<N> and one table aggregates them
    # (empty: a single run of --seed into <output_dir>)
    seeds: list[int] = field(default_factory=list)
    # perturbed-expert episodes in the pretraining dataset, and world-model updates on it.
    # 1536 + 12000 (was 768 + 4000) ranks the planner's candidates better (Spearman .13 ->
    # .22 against the simulator) and lifts SimDist on slippery_slope from +3% to +18% of the
    # commanded distance at 8 min (3 seeds, disjoint CIs; benchmarks/README.md, "What would
    # perfect dynamics give?"); the whole default run, planner H20, measured 27.9 min end to
    # end on 2 quiet cores, 2026-11-26).
    dataset_episodes: int = 1536
    dataset_shard_episodes: int = 32  # episodes per shard (the unit of resume and workers)
    # processes stepping each shard's worlds (TorchRL's ParallelEnv; the shards themselves
    # run side by side per `jobs`). Not part of the results: a shard is the same bytes
    # whichever process makes it, so a run may resume (or be copied) with another count.
    dataset_workers: int = 1
    # Gaussian action noise on every step outside the perturbation bursts
    # (PerturbationSchedule.dither_std; 0: the reference schedule), so the dynamics see
    # small action changes like the planner's proposal noise. 0.3 measured (3 seeds):
    # slippery_slope 8 min 18% either way (benchmarks/README.md, "Small action noise")
    dataset_dither_std: float = 0.0
    # world-model size (simdist.modules.SIMDIST_SIZES). "wide" (MLPs 512 wide) over "small"
    # (256): slippery_slope +28 [19, 37] / +20 [9, 31] points at 2 / 8 minutes, 3 seeds
    # paired (benchmarks/README.md, "Run to run, an ensemble of pretrainings, and a larger
    # model"); bfloat16 training (below) pays for its 2.6x cost per update.
    model_size: str = "wide"
    # observation steps the encoder reads (0: the size's own, 4 for "small"; the SimDist
    # reference: 25)
    model_history: int = 0
    # width of the dynamics MLP alone (0: the size's own hidden width). The dynamics is the
    # one part SimDist finetunes and the one the planner runs at every step of every
    # candidate: 1024 instead of 512 costs ~1.5x the planner time (bfloat16, one thread).
    model_dynamics_hidden: int = 0
    # latent size (0: the size's own, 64; the SimDist reference: 64, TD-MPC2: 512). SimNorm
    # keeps groups of 8 (TD-MPC2's simnorm_dim), so it must be a multiple of 8. 256, the
    # default since 2026-12-05: slippery_slope after 8 minutes 53% [46, 59] against 46%
    # [39, 52] with 128, paired +7 [0, 13] (+7 on every seed), foam +7 [4, 9], weak_motors
    # -1 [-7, 5], laggy -6 [-11, -2] (three seeds each, per episode; by seed +7 / -13 / -13:
    # a cost on two of three pretrainings); 28 min 40 s end to end on 2 Intel cores ("A
    # 256-dimensional latent on today's default"). 128 over 64
    # (2026-11-27): slippery_slope 8 minutes +12 [3, 21], every seed higher ("More capacity
    # where the model is finetuned"). The value applies whatever --model-size says (0
    # keeps that size's own). A folder from before the field was made with the size's own
    # latent; one made before 2026-12-05 resumes with --model-latent-dim 128.
    model_latent_dim: int = field(default=256, metadata={ABSENT_MEANS: 0})
    # the encoder also reads the action sent one step before each observation of its window
    # (HistoryEncoder(action_dim=)): with actuation latency (0-1 steps in the training
    # randomisation, 3 in `laggy`) the commands still in flight decide the next states,
    # and only a latent that carries them lets dynamics-only finetuning learn a new delay.
    # slippery_slope after 8 minutes, three seeds paired on the same worlds: see
    # benchmarks/README.md, "The previous action as an encoder input". A folder from before
    # the field was made without it.
    model_previous_action: bool = field(default=True, metadata={ABSENT_MEANS: False})
    # how the dynamics steps a SimNorm latent (MLPDynamics(residual=)): "additive" norm(z +
    # f), every model until 2026-12-03, is not an identity residual under SimNorm (f = 0
    # gives softmax(z), a blurred copy); "logit" norm(log z + f), f zero-initialised,
    # starts at "no change" and learns the change: the default since 2026-12-03
    # (slippery_slope, three seeds paired with "additive" on the same datasets and worlds:
    # benchmarks/README.md, "A dynamics that starts at no change"). A folder from before
    # the field was made with "additive".
    model_dynamics_residual: str = field(default="logit", metadata={ABSENT_MEANS: "additive"})
    # the policy prior's output box: False, tanh in [-1, 1] (every model until 2026-12-03);
    # True, the data task's per-joint action bounds (PolicyPrior(action_low=, action_high=)):
    # the quadruped's lift joints allow up to 1.1 and the expert's unperturbed actions
    # exceed 1.0 there on 7-13% of steps, which a [-1, 1] prior cannot imitate. Measured
    # (three seeds, latent 256): it fits those steps with a third of the error, yet plans
    # level: slippery_slope 8 minutes +2 [-5, 9], laggy +4 [-1, 8] (benchmarks/README.md,
    # "A policy prior that reaches the lift joints' 1.1"), so it stays off.
    model_prior_bounds: bool = False
    # precision of the world model's training updates: "none" (float32), "bfloat16"
    # (autocast forward pass, float32 weights and latents; SimDistConfig.mixed_precision)
    # or "auto": bfloat16 where the device has native bfloat16 matmuls, float32 elsewhere
    # (simdist.utils.precision; results.json records what it resolved to). Planning has its
    # own setting (planner_precision). bfloat16 trains the wide model 2.3-2.6x faster on a
    # CPU with AVX512-BF16 and 16-25x slower on one with AVX2 only
    # (benchmarks/simdist_pretrain_precision.py); transfer as in float32, three seeds
    # (benchmarks/README.md, "Run to run, an ensemble of pretrainings, and a larger model").
    # (A folder from before the field existed trained in float32; one made before "auto"
    # became the default, 2026-12-02, resumes with --mixed-precision bfloat16.)
    mixed_precision: str = field(default="auto", metadata={ABSENT_MEANS: "none"})
    # steps of latent rollout in the pretraining and finetuning losses. Shorter than the
    # planner's horizon on purpose: training over the planner's 10 steps ranked candidates
    # worse (Spearman .07 vs .23) and planned the same (slippery_slope 8 min: +17% vs +18%,
    # 3 seeds; benchmarks/README.md, "Does training the model over the planner's horizon help?")
    model_horizon: int = 5
    # robot-observation groups the world model's encoder does not read (names from the
    # task's observation layout, e.g. toe_force, accelerometer, joint_vel). The expert and
    # the dataset are unchanged; the encoder zeroes those inputs (HistoryEncoder
    # ignored_inputs). [] reads everything.
    model_ignored_observations: list[str] = field(default_factory=list)
    # world models pretrained (same dataset, different initialisation and batches) and
    # planned with together (simdist.modules.WorldModelEnsemble); each member's dynamics is
    # finetuned as itself, the whole-model ablation likewise. K costs K x the pretraining,
    # finetuning and planner time, so the CPU default keeps 1. Three finetuned models
    # planned together reached 30% of the commanded distance on slippery_slope against
    # 26% for the best of them alone and 11% on average (benchmarks/README.md, "Several
    # world models").
    ensemble_size: int = 1
    # with ensemble_size K > 1: the members share one encoder and the reward, value and
    # policy heads, and only their K dynamics differ (pretrained together by
    # SimDistPretrainLoss(extra_dynamics=); one pretraining at ~2.5x a single model's cost
    # at K = 3 instead of 3x, and SimDist's dynamics-only finetuning keeps them shared;
    # the whole-model ablation finetunes each member as its own model, so its encoders
    # drift apart). False: K independent models. Measured at K = 3 (3 seeds, slippery_slope):
    # zero-shot 8% of the commanded distance (default -5%), 2 minutes of target data 16%
    # (default 15%): no gain after finetuning (benchmarks/README.md, "A dynamics ensemble
    # on one encoder").
    ensemble_shared_encoder: bool = False
    # processes that pretrain (and each round finetune) the K members side by side (0: as
    # many as the torch threads allow, one thread or more each; 1: one after the other in
    # this process). Small models use two threads poorly, so two one-thread processes
    # train two members in 1.2-1.45x one member's time, depending on the host
    # (benchmarks/parallel_members.py; benchmarks/README.md, "Two members of half the
    # updates"). A
    # member's weights depend on its seed and thread count only, so this changes no
    # figure beyond what --threads does. Not part of the results.
    ensemble_jobs: int = 0
    # processes for the independent parts of the stages: the dataset's shards, the
    # zero-shot stage's two evaluations, a round's collection batches, its three methods
    # (each finetuned and evaluated in its own process) and the two recordings (0: as many
    # as the torch threads allow, one thread or more each; 1: one after the other in this
    # process). With members (ensemble_size > 1) a round's methods stay one after the
    # other, their members side by side (ensemble_jobs). A shard is the same bytes in any
    # process. A second torch thread speeds the planner up only 1.5-1.8x, so
    # on 2 cores the zero-shot stage took 146 s side by side against 196 s in one process
    # (benchmarks/README.md, "Side by side: the recipe's planner stages on two cores"). A
    # figure depends on its seeds and each process's thread count only, so this changes no
    # figure beyond what --threads does. Not part of the results.
    jobs: int = 0
    pretrain_updates: int = 12000  # world-model updates on the dataset (batch_slices slices each)
    probe_updates: int = 1000  # latent -> state probe for the rerun recordings only
    # rerun recordings and videos of one target episode before and after finetuning (and
    # the probe they draw). Off for sweeps that only need the tables: a rerun with it on
    # adds them to a finished folder.
    record: bool = True
    # Value labels are discounted returns, up to 1/(1-gamma) = 100 rewards: weighting their
    # squared error by ~(1-gamma)^2 regresses V/100 at weight 1 (errors of 0.1 in V/100
    # would otherwise cost 100x the consistency term in the shared encoder).
    value_weight: float = 1e-3
    heldout_episodes: int = 32  # fresh-seed episodes for the latent prediction diagnostic
    slice_len: int = 16  # steps per training slice
    batch_slices: int = 32  # slices per update
    # latent MPPI: planning horizon (steps; 20 = 0.4 s at 50 Hz). The longer the plan, the
    # more of a candidate's score the (finetuned) dynamics decide rather than the frozen
    # terminal value: on slippery_slope, three seeds of the current pretraining, SimDist
    # after 8 minutes of target data reaches 31% [26, 37] of the commanded distance at H20
    # against 21% [15, 28] at H10 (paired +10 [3, 17]; sim 94% vs 92%; benchmarks/README.md,
    # "The simulator ceiling of today's pretraining, and a 20-step planner"). Planner time
    # grows linearly with it.
    planner_horizon: int = 20
    planner_samples: int = 64  # latent MPPI: action sequences per iteration
    planner_iterations: int = 3  # latent MPPI: refinement iterations per step
    planner_elites: int = 8  # latent MPPI: elites kept per iteration
    # latent MPPI: share of the samples proposed by the policy prior, and the noise added
    # to them. The reference's 5% (+ noise 0.05) lets 61 of 64 wide random samples exploit
    # the errors of a model pretrained on 192k transitions: in sim, seed 1's prior alone
    # reaches 90% of the commanded distance, planning with 5% proposals -4%, with 90%
    # (+ noise 0.3, a trust region around the prior) 105% (benchmarks/README.md, "Planner
    # variants"). The paper preset keeps the reference values.
    planner_policy_fraction: float = 0.9
    planner_policy_noise: float = 0.3  # latent MPPI: std of the noise on the prior's proposals
    # latent MPPI: steps at the start of the plan on which the prior's proposals carry that
    # noise (PlannerConfig.policy_noise_steps; 0: every step of the horizon). 1 measured
    # (slippery_slope, 3 seeds, 8 min): 28% [21, 35] vs 31% [26, 37], paired -3 [-12, 5]
    # (benchmarks/README.md, "Which candidates should the planner compare").
    planner_policy_noise_steps: int = 0
    # latent MPPI: a candidate's score mixes the values read along its plan, a
    # lambda-return (PlannerConfig.value_lambda; 1: the terminal value alone, as the
    # reference and every default before 2026-12-06 evening). Measured on slippery_slope
    # through the whole recipe (every step's value), five seeds paired with the previous
    # default's runs: 8 minutes 67% against 56% (+11 [+7, +16]), zero-shot 42% against 29%
    # (benchmarks/README.md, "The lambda-return over five seeds").
    planner_value_lambda: float = field(default=0.95, metadata={ABSENT_MEANS: 1.0})
    # the lambda-return's values at every k-th predicted step only, mixed with lambda^k
    # (PlannerConfig.value_every; 1: at each step): the same weighting for fewer value-head
    # calls. 2 on six fixed 8-minute models: -1.1 [-3.4, +1.3] points against every step,
    # at ~1.1-1.3x the terminal-value planner's call instead of ~1.4-1.5x (the same section).
    planner_value_every: int = field(default=2, metadata={ABSENT_MEANS: 1})
    # steps of action delay the planner compensates (PlannerConfig.latency_compensation; the
    # SimDist reference: 1). Off: on laggy it lifted the previous default's pretrained models
    # (seeds 0-2: 89/82/91% -> 115/102/109% of the commanded distance) but not the current
    # ones (82/95/75% -> 93/61/104%; benchmarks/README.md, "One step of latency compensation").
    planner_latency_compensation: int = 0
    # commands the prior's proposals are also drawn for (PlannerConfig.proposal_commands;
    # empty: off): the history is encoded under each of them too and the prior rolled from
    # those latents, every candidate scored for the episode's own command. 0.25 0.5 0.75
    # measured on slippery_slope (seeds 3 and 4's 8-minute models, paired): -0 [-6, 5] and
    # +8 [-3, 20]; the whole recipe on seed 3 -11 / -9 points at 2 / 8 minutes
    # (benchmarks/README.md, "Command-diverse proposals"): not better, so off.
    planner_proposal_commands: tuple[float, ...] = ()
    # arithmetic of the planner's candidate rollouts (PlannerConfig.precision): "none"
    # (float32), "bfloat16" (autocast; scores and the MPPI update stay float32) or "auto"
    # (bfloat16 where the device has native bfloat16 matmuls, as mixed_precision). bfloat16
    # plans 2.6x faster on AVX512-BF16 cores and the same models just as well:
    # slippery_slope, 3 seeds' 2-minute models and one 8-minute model, paired with float32
    # on the same worlds -2 [-9, 5] points (benchmarks/README.md, "bfloat16 planning"); on
    # AVX2-only cores it plans several times slower. A folder from before the field reads
    # as float32, so old runs resume as they were made; one made before "auto" became the
    # default (2026-12-02) resumes with --planner-precision bfloat16.
    planner_precision: str = field(default="auto", metadata={ABSENT_MEANS: "none"})
    # the planner that collects each round's target data, where it differs from the one
    # that is evaluated (0: the planner's own samples / iterations / elites). Members
    # finetuned on data a 48 x 2 (6 elites) two-member planner collected plan as well as
    # those whose data the full 64 x 3 search collected (slippery_slope, seeds 3 and 4,
    # 8 minutes, both evaluated at 64 x 3: 66% vs 67%), while evaluating with the cheap
    # search costs ~7 points (benchmarks/README.md, "Two members at one model's planner
    # cost, through the whole recipe"). So the default collects with 48 x 2 (6 elites),
    # about half the search, and evaluates with the full one: one model on slippery_slope,
    # three seeds paired with the full search's collection: 8 minutes +0 [-4, +4] points
    # (64% either way), 2 minutes +7 [0, +13] (benchmarks/README.md, "Within 30 minutes").
    collect_planner_samples: int = field(default=48, metadata={ABSENT_MEANS: 0})
    collect_planner_iterations: int = field(default=2, metadata={ABSENT_MEANS: 0})
    collect_planner_elites: int = field(default=6, metadata={ABSENT_MEANS: 0})
    # target rounds: cumulative minutes of 50 Hz target data after each round. Two rounds
    # (3.6 and 4.9 min on 2 cores with the wide model) keep the whole run at ~21 min
    # (README, recipe section); --budgets-min 1 2 4 8 for the curve.
    budgets_min: list[float] = field(default_factory=lambda: [2.0, 8.0])
    collect_episodes: int = 12  # worlds stepped at once while collecting
    # target-data collection only: a world whose robot rolls onto its back (body-frame
    # gravity z below UPSIDE_DOWN) ends its episode there and starts a new one, as a
    # fallen robot is set back on its feet when real data is recorded. Without it the
    # rest of such an episode is the robot flailing on its back: on slippery_slope the
    # slow command rolled over in 19-100% of the episodes the planner collected
    # (benchmarks/README.md, "Where the gap to 60% lies"). The budget in steps is the
    # same; the finetuning losses drop every prediction across a reset; evaluation
    # episodes always run their full length.
    collect_reset_upside_down: bool = False
    # The task reward's exponent of its upright term, for every stage that records or
    # reads rewards (the dataset, target data, evaluations; the committed expert was
    # trained with 1). At 1 a 30-degree tilt still pays 0.93, so neither the reward head
    # nor the 20-step plan sees this quadruped rear up before it goes over the tail
    # (benchmarks/README.md, "How the slow command falls"); at 10 it pays half. Measured
    # at 10 (three seeds): falls after finetuning nearly gone, slippery_slope progress
    # level (-4 [-11, +2] at 8 minutes; "A reward that sees the rearing"), so 1 stays.
    reward_upright_power: float = 1.0
    finetune_updates: int = 1000  # per round, for every method (same data, same updates)
    finetune_lr: float = 1e-4  # dynamics-only (and whole-model ablation) learning rate
    # finetuning terms through the frozen heads (DynamicsFinetuneLoss; the ablation gets the
    # same loss): recorded target rewards on predicted latents, and the frozen value head on
    # predicted vs encoded latents. 0 / 0: consistency alone, the reference's finetuning.
    finetune_reward_weight: float = 0.0
    finetune_value_weight: float = 0.0
    # the finetuning's consistency term, for both finetuned methods: "squared" (the
    # pretraining's squared error, the reference) or "kl", each SimNorm group of the
    # predicted latent against the encoded one as categorical distributions, whose
    # gradient does not fade where the pretrained dynamics is confidently wrong
    # (objectives.simdist_pretrain.consistency_error). Measured (slippery_slope, three
    # seeds paired on shared pretrainings): 8 minutes -3 [-9, +4] points; the groups are
    # soft (no top entry above 0.9), so nothing is confidently wrong (benchmarks/README.md,
    # "A KL consistency loss for finetuning").
    finetune_consistency: str = field(default="squared", metadata={ABSENT_MEANS: "squared"})
    # prioritised finetuning slices (data/prioritised_slices.py): a slice is drawn with
    # probability ~ (its consistency error under the model being finetuned)^alpha, with
    # importance weights ^beta. 0: uniform slices (TorchRL's SliceSampler), the reference.
    # Applies to both finetuned methods (SimDist and the whole-model ablation). With alpha
    # > 0 the logged finetuning losses are importance-weighted means (with beta < 1 they
    # lean towards the worst slices): compare runs by their evaluations, not their losses.
    finetune_priority_alpha: float = 0.0
    finetune_priority_beta: float = 0.4
    # co-training: the share of each finetuning batch's slices drawn from the simulation
    # dataset the model was pretrained on (data.CoTrainingSlices), the rest from the target
    # data, for both finetuned methods. It keeps the finetuned part fitted where the few
    # minutes of target data say nothing. 0: target slices only, the reference. Half
    # (0.5) measured on slippery_slope, seeds 0 and 2: level at 2 minutes, -15 [-25, -7]
    # points at 8 (the fastest command 15% against 47%); on foam -4 [-9, 0]
    # (benchmarks/README.md, "Co-training with the simulation dataset").
    finetune_sim_fraction: float = field(default=0.0, metadata={ABSENT_MEANS: 0.0})
    sac_batch_size: int = 256  # continued-SAC baseline batch size
    output_dir: str = "outputs/simdist_quadruped"  # stages, results and plots go here
    # where the world model and probe train and plan ("cpu", "cuda", "auto"); envs, the
    # dataset, the expert and the SAC baseline stay on the CPU. Not part of the results.
    device: str = "cpu"
    # scalar logs of every training update under <output_dir>/logs: csv, tensorboard
    # (needs tensorboard), wandb (offline; needs wandb) or none. Not part of the results.
    logger: str = "csv"
    # torch CPU threads of this process (0: torch's default, one per core). Figures depend
    # on it: PyTorch splits float reductions by thread, so the same seed trains a slightly
    # different model with 1 and 2 threads (results.json records the count used). Not part
    # of the results: a run may resume with another count.
    threads: int = 0

    def __post_init__(self):
        check(self.task in TASKS, "task", f"unknown task {self.task!r}; valid: {sorted(TASKS)}")
        check(self.data_task in TASKS, "data_task",
              f"unknown task {self.data_task!r}; valid: {sorted(TASKS)}")
        for name, targets in (("target", [self.target]), ("expert_targets", self.expert_targets)):
            for target in targets:  # a registered name, a JSON object or a .json file
                check_builds(name, get_target, target)
        check(self.model_size in SIMDIST_SIZES, "model_size",
              f"unknown size {self.model_size!r}; valid: {sorted(SIMDIST_SIZES)}")
        check(self.model_dynamics_residual in DYNAMICS_RESIDUALS, "model_dynamics_residual",
              f"unknown residual {self.model_dynamics_residual!r}; valid: "
              f"{list(DYNAMICS_RESIDUALS)}")
        check(self.finetune_consistency in CONSISTENCY_KINDS, "finetune_consistency",
              f"unknown consistency {self.finetune_consistency!r}; valid: "
              f"{list(CONSISTENCY_KINDS)}")
        for name in ("mixed_precision", "planner_precision"):
            check(getattr(self, name) in PRECISIONS, name,
                  f"unknown precision {getattr(self, name)!r}; valid: {list(PRECISIONS)}")
        check_positive(self, "expert_frames", "episodes", "episode_steps", "dataset_episodes",
                       "dataset_shard_episodes", "dataset_workers", "model_horizon",
                       "heldout_episodes", "slice_len", "batch_slices", "collect_episodes",
                       "finetune_lr", "sac_batch_size", "pretrain_updates", "ensemble_size",
                       "reward_upright_power")
        check_positive(self, "probe_updates", "finetune_updates", "value_weight",
                       "model_history", "model_dynamics_hidden", "model_latent_dim", "threads",
                       "ensemble_jobs", "jobs", "collect_planner_samples",
                       "collect_planner_iterations", "collect_planner_elites",
                       "finetune_reward_weight", "finetune_value_weight",
                       "finetune_priority_alpha", "finetune_priority_beta",
                       "finetune_sim_fraction", allow_zero=True)
        sim_slices = self.finetune_sim_slices()
        check(self.finetune_sim_fraction < 1 and (self.finetune_sim_fraction == 0
                                                  or 0 < sim_slices < self.batch_slices),
              "finetune_sim_fraction", f"needs 0 <= fraction < 1 leaving at least one "
              f"simulation and one target slice of the {self.batch_slices} per batch, got "
              f"{self.finetune_sim_fraction} ({sim_slices} simulation slices)")
        check(self.finetune_sim_fraction == 0 or self.finetune_priority_alpha == 0,
              "finetune_sim_fraction", "cannot be combined with --finetune-priority-alpha "
              "(the priorities rank target slices only)")
        check(self.model_latent_dim % SIMNORM_GROUP == 0, "model_latent_dim",
              f"must be a multiple of {SIMNORM_GROUP} (SimNorm's group), got {self.model_latent_dim}")
        check(self.model_horizon < self.slice_len <= self.episode_steps, "slice_len",
              f"needs model_horizon < slice_len <= episode_steps, got {self.model_horizon}, "
              f"{self.slice_len}, {self.episode_steps}")
        # a training start t counts only once its encoder window lies inside the slice
        # (complete_windows), so a slice must leave one start at t >= context - 1
        history = self.model_history or SIMDIST_SIZES[self.model_size]["history"]
        context = history + (1 if self.model_previous_action else 0)
        check(self.slice_len - self.model_horizon >= context, "slice_len",
              f"needs slice_len >= model_horizon + {context} (the steps one encoder window "
              f"reads: history {history}"
              f"{' + the previous action' if self.model_previous_action else ''}), got "
              f"{self.slice_len}: no start of a slice would see a whole window")
        check(len(self.budgets_min) > 0 and all(b > 0 for b in self.budgets_min)
              and all(a < b for a, b in zip(self.budgets_min, self.budgets_min[1:])),
              "budgets_min", f"must be positive and increasing, got {self.budgets_min}")
        check(len(set(self.seeds)) == len(self.seeds), "seeds", f"repeated seeds {self.seeds}")
        check(self.ensemble_size > 1 or not self.ensemble_shared_encoder, "ensemble_shared_encoder",
              "needs --ensemble-size > 1 (one model has nothing to share)")
        if self.model_ignored_observations:
            layout = observation_layout(self.data_task)
            check(layout is not None, "model_ignored_observations",
                  f"data task {self.data_task!r} has no robot observation to hide groups of")
            names = layout.names()
            unknown = [g for g in self.model_ignored_observations if g not in names]
            check(not unknown, "model_ignored_observations",
                  f"unknown observation groups {unknown}; valid: {names}")
            check(len(set(self.model_ignored_observations)) < len(names),
                  "model_ignored_observations", "would hide every observation group")
        check_builds("planner_*", self.planner)
        check_builds("collect_planner_*", self.collect_planner)
        check_builds("dataset_*", dataset_config, self)
        check_builds("device", resolve_device, self.device)
        check(self.logger in LOGGERS, "logger", f"must be one of {LOGGERS}, got {self.logger!r}")
        visual = [t for t in [self.target, *self.expert_targets] if get_target(t).visual]
        check(not visual, "target", f"{visual} change only what a camera sees; SimDist's "
              "world model observes proprioception and the height scan (use recipes/twist_dmc.py)")
        if self.target not in self.expert_targets:
            self.expert_targets = [*self.expert_targets, self.target]

    def finetune_sim_slices(self) -> int:
        """Slices of each finetuning batch drawn from the simulation dataset."""
        return round(self.finetune_sim_fraction * self.batch_slices)

    def planner(self) -> PlannerConfig:
        return PlannerConfig(horizon=self.planner_horizon, num_samples=self.planner_samples,
                             iterations=self.planner_iterations, num_elites=self.planner_elites,
                             policy_fraction=self.planner_policy_fraction,
                             policy_noise=self.planner_policy_noise,
                             policy_noise_steps=self.planner_policy_noise_steps,
                             value_lambda=self.planner_value_lambda,
                             value_every=self.planner_value_every,
                             latency_compensation=self.planner_latency_compensation,
                             proposal_commands=self.planner_proposal_commands,
                             precision=self.planner_precision)

    def collect_planner(self) -> PlannerConfig:
        """The planner that collects target data: :meth:`planner` with the
        ``collect_planner_*`` fields that are set (non-zero) in place of its own."""
        search = {"num_samples": self.collect_planner_samples,
                  "iterations": self.collect_planner_iterations,
                  "num_elites": self.collect_planner_elites}
        return dataclasses.replace(self.planner(), **{k: v for k, v in search.items() if v})


PRESETS = {
    "default": {},
    "tiny": {"episodes": 2, "episode_steps": 20, "heldout_episodes": 2, "expert_targets": ["sim", "slippery_slope"],
             "dataset_episodes": 4, "dataset_shard_episodes": 2, "model_size": "tiny",
             "model_latent_dim": 0,
             "model_horizon": 3, "pretrain_updates": 4, "slice_len": 8, "batch_slices": 4,
             "planner_horizon": 3, "planner_samples": 16, "planner_iterations": 1,
             "planner_elites": 4, "budgets_min": [0.02, 0.04], "collect_episodes": 2,
             "finetune_updates": 3, "sac_batch_size": 16, "probe_updates": 3,
             # collects with its own (smaller) planner
             "collect_planner_samples": 0, "collect_planner_iterations": 0,
             "collect_planner_elites": 0},
    "paper": {"episodes": 15, "episode_steps": 500, "dataset_episodes": 8192,
              "dataset_shard_episodes": 64, "dataset_workers": 4, "model_size": "paper",
              "model_latent_dim": 0,  # the reference's 64
              # the reference collects with the planner it evaluates
              "collect_planner_samples": 0, "collect_planner_iterations": 0,
              "collect_planner_elites": 0,
              "mixed_precision": "none",  # the GPU path as measured (float32)
              "planner_precision": "none",
              # 51: the reference's 25-step history and 25-step horizon, plus the step
              # whose action the window's first step reads as its previous action
              "model_horizon": 25, "pretrain_updates": 100_000, "slice_len": 51,
              "batch_slices": 16, "planner_horizon": 25, "planner_samples": 450,
              "planner_iterations": 8, "planner_elites": 64, "planner_policy_fraction": 0.05,
              "planner_policy_noise": 0.05,
              "planner_value_lambda": 1.0, "planner_value_every": 1,  # terminal value alone
              "budgets_min": [16.0, 27.0, 36.0], "collect_episodes": 32,
              "finetune_updates": 5000},
}


# -- stages -----------------------------------------------------------------------------
def expert_stage(cfg: Config, stage_dir: Path) -> dict:
    """Loads the committed expert, or retrains it (resumable) when asked."""
    path = resolve_expert(cfg.expert)  # the default is shipped as package data
    if cfg.retrain_expert:
        path = train_sac_expert(SACExpertConfig(task=cfg.data_task, total_frames=cfg.expert_frames,
                                                seed=cfg.seed), stage_dir)
    if not path.exists():
        raise FileNotFoundError(
            f"no expert checkpoint at {path}: train one with `python recipes/train_expert.py` "
            "or rerun this recipe with --retrain-expert")
    Expert.load(path)  # fails clearly on a corrupt or incompatible file
    return {"path": str(path)}


def evaluate(cfg: Config, target: str, policy, primers=(), seed_offset: int = 10_000) -> dict:
    """Forward progress of ``policy`` over ``cfg.episodes`` episodes in ``target``.

    Every method is evaluated on the same seeds (same initial states and speeds).
    """
    env = locomotion_env(get_target(target), cfg.episodes, cfg.episode_steps,
                         cfg.seed + seed_offset, primers=primers, task=cfg.task,
                         upright_power=cfg.reward_upright_power)
    stats = episode_stats(rollout(env, policy, cfg.episode_steps, desc=f"evaluate in {target}"),
                          env.base_env.observation_layout)
    env.close()
    return stats


def expert_zero_shot_stage(cfg: Config, expert_path: str) -> dict:
    policy = Expert.load(expert_path).deterministic()
    return {t: evaluate(cfg, t, policy) for t in tqdm(cfg.expert_targets, desc="expert zero-shot")}


def dataset_config(cfg: Config) -> DatasetConfig:
    return DatasetConfig(task=cfg.data_task, episodes=cfg.dataset_episodes,
                         episode_steps=cfg.episode_steps, shard_episodes=cfg.dataset_shard_episodes,
                         num_workers=cfg.dataset_workers, seed=cfg.seed,
                         schedule=PerturbationSchedule(dither_std=cfg.dataset_dither_std),
                         upright_power=cfg.reward_upright_power)


def load_experts(expert_path: str) -> tuple[Expert, list[Expert]]:
    """The final expert and its earlier snapshots (the dataset's policy mixture)."""
    snapshots = sorted(load_checkpoint(expert_path)["snapshots"])
    return Expert.load(expert_path), [Expert.load(expert_path, snapshot=s) for s in snapshots]


def dataset_stage(cfg: Config, expert_path: str, stage_dir: Path) -> dict:
    jobs, threads = stage_jobs(cfg, dataset_config(cfg).shards)
    path = generate_dataset(dataset_config(cfg), stage_dir / "data", *load_experts(expert_path),
                            jobs=jobs, threads=threads)
    meta = read_dataset_meta(path)
    data = load_memmap(path / "data", manifest=meta["files"])
    return {"path": str(path), "transitions": meta["transitions"], "bytes": meta["bytes"],
            "generation_s": meta["seconds"],
            "noised_fraction": data["noised"].float().mean().item(),
            "final_expert_unnoised_fraction": data["expert_active"].float().mean().item()}


def heldout_prediction_skill(cfg: Config, agent: SimDistAgent, expert_path: str
                             ) -> dict[str, list[float]]:
    """Latent prediction error relative to the latent's variance, per step of the model's
    horizon, on perturbed-expert episodes from seeds the dataset never used, beside the
    no-change and wrong-action references (:func:`latent_prediction_skill`)."""
    data_cfg = dataclasses.replace(dataset_config(cfg), episodes=cfg.heldout_episodes,
                                   shard_episodes=cfg.heldout_episodes, num_workers=1)
    # shard indices past the dataset's own are fresh seeds (see simdist.data.shard_seed)
    episodes = generate_shard(data_cfg, dataset_config(cfg).shards + 1, *load_experts(expert_path))
    with torch.no_grad():
        return latent_prediction_skill(agent.world_model, episodes.to(agent.device),
                                       cfg.model_horizon)


@functools.lru_cache(maxsize=None)
def observation_layout(task: str) -> Layout:
    """The robot observation's named groups for ``task`` (read off one world)."""
    env = make_env(task, seed=0)
    try:
        return env.observation_layout
    finally:
        env.close()


def ignored_inputs(cfg: Config) -> list[int]:
    """Observation indices of ``cfg.model_ignored_observations``."""
    layout = observation_layout(cfg.data_task)
    return sorted(i for g in cfg.model_ignored_observations
                  for i in range(*layout[g].indices(layout.size)))


def new_agent(cfg: Config, obs_dim: int, action_dim: int, dynamics_members: int = 1
              ) -> SimDistAgent:
    overrides = {"history": cfg.model_history} if cfg.model_history else {}
    if cfg.model_dynamics_hidden:
        overrides["dynamics_hidden"] = cfg.model_dynamics_hidden
    if cfg.model_latent_dim:
        overrides.update(latent_dim=cfg.model_latent_dim,
                         simnorm_groups=cfg.model_latent_dim // SIMNORM_GROUP)
    if cfg.model_ignored_observations:
        overrides["ignored_inputs"] = ignored_inputs(cfg)
    if cfg.model_previous_action:
        overrides["previous_action"] = True
    overrides["dynamics_residual"] = cfg.model_dynamics_residual
    if cfg.model_prior_bounds:
        env = make_env(cfg.data_task)
        overrides["prior_bounds"] = action_bounds(env.action_spec)
        env.close()
    wm = SimDistWorldModel.build(obs_dim, action_dim, size=cfg.model_size, **overrides)
    return SimDistAgent(wm, SimDistConfig(size=cfg.model_size, horizon=cfg.model_horizon,
                                          finetune_lr=cfg.finetune_lr,
                                          value_weight=cfg.value_weight,
                                          finetune_reward_weight=cfg.finetune_reward_weight,
                                          finetune_value_weight=cfg.finetune_value_weight,
                                          finetune_consistency=cfg.finetune_consistency,
                                          dynamics_members=dynamics_members,
                                          mixed_precision=cfg.mixed_precision),
                        planner_config=cfg.planner()).to(cfg.device)


def save_agent(cfg: Config, agent: SimDistAgent, path: Path, **meta) -> str:
    """A self-describing agent file (``SimDistAgent.load`` / ``recipes/evaluate.py``)."""
    agent.save(path, optimisers=False, meta={"task": cfg.task, "seed": cfg.seed, **meta})
    return str(path)


def term_shares(metrics: dict) -> dict:
    """Each loss term's share of the summed loss (how much each shapes the latent)."""
    terms = {k: v for k, v in metrics.items() if k.startswith("loss_")}
    total = sum(terms.values()) or 1.0
    return {k: v / total for k, v in terms.items()}


def member_dir(stage_dir: Path, i: int) -> Path:
    """Member ``i``'s pretraining folder (member 0: the stage folder itself)."""
    return stage_dir if i == 0 else stage_dir / f"member_{i}"


def pretrain_member(cfg: Config, buffer, data, expert_path: str, stage_dir: Path, i: int,
                    logger=None) -> tuple[SimDistAgent, list[dict]]:
    """Member ``i`` of the pretrained ensemble (member 0: the single model of K = 1, its
    initialisation drawn from the generator as the caller left it)."""
    if i:
        torch.manual_seed(stage_seed(cfg.seed, f"pretrain/member_{i}/init"))
    obs = data["observation"]
    shared = cfg.ensemble_size if cfg.ensemble_shared_encoder else 1
    agent = new_agent(cfg, obs.shape[-1], data["action"].shape[-1], dynamics_members=shared)
    flat = obs.reshape(-1, obs.shape[-1])
    agent.world_model.encoder.set_normalisation(flat.mean(0), flat.std(0))
    folder = member_dir(stage_dir, i)
    folder.mkdir(parents=True, exist_ok=True)
    history = train_resumable(
        agent.pretrain_update, lambda: buffer.sample().reshape(-1, cfg.slice_len),
        cfg.pretrain_updates, {"world_model": agent.world_model, "optim": agent.pretrain_optim,
                               **({"extra_dynamics": agent.pretrain_loss.extra_dynamics}
                                  if shared > 1 else {})},
        folder / "training.pt",
        desc="pretrain world model" + (f" (member {i})" if i else ""),
        seed=stage_seed(cfg.seed, "pretrain" if i == 0 else f"pretrain/member_{i}"),
        logger=logger, log_prefix="pretrain" if i == 0 else f"pretrain/member_{i}")
    save_atomic(agent.world_model.state_dict(), folder / "world_model.pt")
    return agent, history


def updates_done(checkpoint: Path) -> int:
    """How many updates a :func:`train_resumable` checkpoint holds (0: none yet)."""
    return len(load_checkpoint(checkpoint)["history"]) if checkpoint.exists() else 0


def log_trained(logger, prefix: str, history: list[dict], done: int) -> None:
    """Logs a worker's updates after the ``done`` its checkpoint already held (workers get
    no logger; a resumed stage logs no update twice)."""
    for step, metrics in enumerate(history[done:], done + 1):
        log_metrics(logger, prefix, metrics, step)


def pretrain_member_job(cfg: Config, dataset: str, expert_path: str, stage_dir: Path,
                        i: int) -> tuple[list[dict], int]:
    """Member ``i``'s pretraining on its own (a :func:`run_jobs` worker), the generator set
    as :func:`pretrain_stage` sets it for member 0, so every member trains as it would in
    the stage's own process; its weights go to its stage folder. Returns its history and
    how many of those updates its checkpoint already held."""
    done = updates_done(member_dir(stage_dir, i) / "training.pt")
    torch.manual_seed(cfg.seed)
    buffer = pretraining_buffer(cfg, dataset)
    return pretrain_member(cfg, buffer, buffer[:], expert_path, stage_dir, i)[1], done


def pretraining_buffer(cfg: Config, dataset: str):
    """The dataset's slices with the entries the pretraining loss reads and no others
    (1.2 ms per sample against 1.8 with every entry; benchmarks/README.md, "Within 30
    minutes")."""
    keys = dataclasses.astuple(SimDistPretrainLoss.default_keys())
    return load_dataset(dataset, cfg.slice_len, cfg.slice_len * cfg.batch_slices, keys=keys)


def member_jobs(cfg: Config, members: int | None = None) -> tuple[int, int]:
    """(processes, torch threads each) for training ``members`` models side by side
    (default: the members pretrained independently; one with a shared encoder)."""
    if members is None:
        members = cfg.ensemble_size if not cfg.ensemble_shared_encoder else 1
    threads = cfg.threads or torch.get_num_threads()
    jobs = max(1, min(members, cfg.ensemble_jobs or threads))
    return jobs, max(1, threads // jobs)


def stage_jobs(cfg: Config, calls: int) -> tuple[int, int]:
    """(processes, torch threads each) for ``calls`` independent planner-stage calls
    (``cfg.jobs``; see its comment)."""
    threads = cfg.threads or torch.get_num_threads()
    jobs = max(1, min(calls, cfg.jobs or threads))
    return jobs, max(1, threads // jobs)


def pretrain_stage(cfg: Config, dataset: str, expert_path: str, stage_dir: Path,
                   logger=None) -> dict:
    jobs, threads = member_jobs(cfg)
    if jobs > 1:  # each member in a worker; the loop below then restores them from disk
        histories = run_jobs([(pretrain_member_job, (cfg, dataset, expert_path, stage_dir, i))
                              for i in range(cfg.ensemble_size)], jobs, threads=threads)
        for i, (history, done) in enumerate(histories):
            log_trained(logger, "pretrain" if i == 0 else f"pretrain/member_{i}", history, done)
    torch.manual_seed(cfg.seed)
    buffer = pretraining_buffer(cfg, dataset)
    data = buffer[:]  # the whole memory-mapped dataset (a view: nothing is copied)
    obs = data["observation"]
    agent, history = pretrain_member(cfg, buffer, data, expert_path, stage_dir, 0, logger)
    agent_file = save_agent(cfg, agent, stage_dir / "agent.pt")
    members = [str(stage_dir / "world_model.pt")]
    for i in range(1, cfg.ensemble_size):
        path = member_dir(stage_dir, i) / "world_model.pt"
        if cfg.ensemble_shared_encoder:  # trained above: member 0's parts, dynamics i
            path.parent.mkdir(parents=True, exist_ok=True)
            save_atomic(agent.members()[i].state_dict(), path)
        else:
            pretrain_member(cfg, buffer, data, expert_path, stage_dir, i, logger)
        members.append(str(path))
    first, last = mean_metrics(history[:50], 50), mean_metrics(history)
    skill = heldout_prediction_skill(cfg, agent, expert_path)
    return {"path": members[0], "members": members, "agent": agent_file,
            "obs_dim": obs.shape[-1], "action_dim": data["action"].shape[-1],
            "dynamics_residual": cfg.model_dynamics_residual,
            "prior_bounds": cfg.model_prior_bounds,
            "first": first, "last": last,
            "term_shares_first": term_shares(first), "term_shares_last": term_shares(last),
            "heldout_prediction_error_rel": skill["model"],
            "heldout_prediction_copy_rel": skill["copy"],
            "heldout_prediction_shuffled_rel": skill["shuffled"]}


def load_finished_run(run: str | Path, **overrides) -> tuple[Config, dict]:
    """The config (with ``overrides``) and the pretrain stage's result of a run folder, for
    tools that reuse a finished run's models (the benchmarks)."""
    run = Path(run)
    stored = read_json(run / "config.json", "recipe config")
    stored = stored.get("config", stored)
    fields = {f.name for f in dataclasses.fields(Config)}
    # a field the folder predates reads as what the folder was made with (StageRunner's rule)
    stored = {**field_defaults(Config), **stored}
    cfg = dataclasses.replace(Config(**{k: v for k, v in stored.items() if k in fields}),
                              **overrides)
    return cfg, read_json(run / "stages" / "pretrain.json", "record of stage 'pretrain'")["result"]


def load_agent(cfg: Config, pretrained: dict, path: str | None = None) -> SimDistAgent:
    # The two residual forms have the same weights' shapes: a pretraining record copied
    # into a folder of the other form would load without complaint and step wrongly.
    trained = pretrained.get("dynamics_residual", "additive")  # records from before it
    if trained != cfg.model_dynamics_residual:
        raise RunFolderError(
            f"the pretrained dynamics ({pretrained['path']}) was trained with "
            f"--model-dynamics-residual {trained}, this run's config says "
            f"{cfg.model_dynamics_residual}: use the setting the weights were trained with")
    bounded = pretrained.get("prior_bounds", False)
    if bounded != cfg.model_prior_bounds:
        raise RunFolderError(
            f"the pretrained policy prior ({pretrained['path']}) was trained with"
            f"{'' if bounded else ' --no-model-prior-bounds'}"
            f"{' --model-prior-bounds' if bounded else ''}, this run's config says "
            f"otherwise: use the setting the weights were trained with")
    agent = new_agent(cfg, pretrained["obs_dim"], pretrained["action_dim"])
    agent.world_model.load_state_dict(load_checkpoint(path or pretrained["path"]))
    return agent


def member_paths(pretrained: dict, paths: list[str] | None = None) -> list[str]:
    """The ensemble members' weights: ``paths`` if given, else the pretrained ones (a run
    from before ensembles has one member)."""
    return list(paths) if paths else pretrained.get("members", [pretrained["path"]])


def planning_agent(cfg: Config, pretrained: dict, paths: list[str] | None = None
                   ) -> SimDistAgent:
    """The agent the planner runs on: the single model, or the members' ensemble."""
    paths = member_paths(pretrained, paths)
    if len(paths) == 1:
        return load_agent(cfg, pretrained, paths[0])
    members = [load_agent(cfg, pretrained, p).world_model for p in paths]
    return SimDistAgent(WorldModelEnsemble(members), planner_config=cfg.planner()).to(cfg.device)


def evaluate_planner(cfg: Config, agent: SimDistAgent, target: str,
                     seed_offset: int = 10_000) -> tuple[dict, TensorDict]:
    """Plans with ``agent``'s world model in ``target``; returns stats and the rollout."""
    env = locomotion_env(get_target(target), cfg.episodes, cfg.episode_steps,
                         cfg.seed + seed_offset, task=cfg.task,
                         upright_power=cfg.reward_upright_power,
                         primers=[agent.make_primer(cfg.planner().latency_compensation)])
    spec = env.action_spec
    policy = agent.policy(spec.space.low[0], spec.space.high[0], cfg.planner(), seed=cfg.seed)
    td = rollout(env, policy, cfg.episode_steps, desc=f"evaluate planner in {target}")
    stats = episode_stats(td, env.base_env.observation_layout)
    env.close()
    return stats, td


def collect_target_data(cfg: Config, agent: SimDistAgent, steps: int, seed: int) -> TensorDict:
    """``steps`` transitions in the target (``[worlds, episode_steps]`` rows) from the
    agent's planner; with ``cfg.collect_reset_upside_down`` a row may hold several
    episodes."""
    return torch.cat([collect_batch(cfg, agent, worlds, batch_seed)
                      for worlds, batch_seed in collection_batches(cfg, steps, seed)], 0)


def collection_batches(cfg: Config, steps: int, seed: int) -> list[tuple[int, int]]:
    """``(worlds, seed)`` of each batch that collects ``steps`` target transitions:
    ``cfg.collect_episodes`` worlds at a time, each batch seeded by its first episode."""
    episodes = max(1, round(steps / cfg.episode_steps))
    return [(min(cfg.collect_episodes, episodes - start), seed + start)
            for start in range(0, episodes, cfg.collect_episodes)]


def collect_batch(cfg: Config, agent: SimDistAgent, worlds: int, seed: int) -> TensorDict:
    """One batch of :func:`collect_target_data`: ``worlds`` episodes stepped at once."""
    env = locomotion_env(get_target(cfg.target), worlds, cfg.episode_steps, seed,
                         task=cfg.task, upright_power=cfg.reward_upright_power,
                         primers=[agent.make_primer(cfg.planner().latency_compensation)],
                         upside_down_termination=(UPSIDE_DOWN if cfg.collect_reset_upside_down
                                                  else None))
    spec = env.action_spec
    policy = agent.policy(spec.space.low[0], spec.space.high[0], cfg.collect_planner(),
                          seed=seed)
    batch = rollout(env, policy, cfg.episode_steps, desc=f"collect in {cfg.target}")
    env.close()
    return batch.select(*TARGET_KEYS)


def collect_batch_job(cfg: Config, pretrained: dict, weights: list[str] | None, worlds: int,
                      seed: int) -> TensorDict:
    """:func:`collect_batch` in a :func:`run_jobs` worker, with the planner on ``weights``
    (None: the pretrained model)."""
    return collect_batch(cfg, planning_agent(cfg, pretrained, weights), worlds, seed)


def collect_round_data(cfg: Config, pretrained: dict, weights: list[str] | None, steps: int,
                       seed: int) -> TensorDict:
    """:func:`collect_target_data` with its batches side by side (:func:`stage_jobs`)."""
    batches = collection_batches(cfg, steps, seed)
    jobs, threads = stage_jobs(cfg, len(batches))
    return torch.cat(run_jobs([(collect_batch_job, (cfg, pretrained, weights, *batch))
                               for batch in batches], jobs, threads=threads), 0)


def member_tag(name: str, i: int) -> str:
    """A method's file stem for member ``i`` (member 0 keeps the single-model name)."""
    return name if i == 0 else f"{name}_member_{i}"


def finetune_member(cfg: Config, k: int, pretrained: dict, path: str, i: int, name: str,
                    what: str, data, sample, stage_dir: Path, logger=None
                    ) -> tuple[str, str, list[dict]]:
    """Member ``i`` of one method of round ``k``: ``cfg.finetune_updates`` resumable updates
    from the weights at ``path``; returns its weights, its agent file and its history."""
    agent = load_agent(cfg, pretrained, path)
    update, optim = ((agent.finetune_update, agent.finetune_optim) if name == "simdist"
                     else (agent.finetune_whole_update, agent.whole_optim))
    state = {"wm": agent.world_model, "opt": optim}
    tag = member_tag(name, i)
    if cfg.finetune_priority_alpha > 0:  # this model's own errors rank the slices
        slices = PrioritisedSlices(data, cfg.slice_len, cfg.batch_slices,
                                   cfg.finetune_priority_alpha, cfg.finetune_priority_beta)
        if not (stage_dir / f"{tag}.ckpt").exists():  # else its checkpoint restores them
            slices.measure_all(agent.finetune_slice_errors)
        sample, update = slices.sample, prioritised_update(update, slices)
        state["priorities"] = slices
    hist = train_resumable(update, sample, cfg.finetune_updates, state,
                           stage_dir / f"{tag}.ckpt",
                           desc=f"round {k + 1}: {what}" + (f" (member {i})" if i else ""),
                           seed=stage_seed(cfg.seed, f"round_{k + 1}/{tag}"),
                           logger=logger, log_prefix=f"round_{k + 1}/{tag}")
    save_atomic(agent.world_model.state_dict(), stage_dir / f"{tag}.pt")
    agent_file = save_agent(cfg, agent, stage_dir / f"{tag}_agent.pt",
                            target=cfg.target, method=name, member=i)
    return str(stage_dir / f"{tag}.pt"), agent_file, hist


def finetune_member_job(cfg: Config, k: int, pretrained: dict, path: str, i: int, name: str,
                        what: str, data_dirs: list[str], dataset: str | None, stage_dir: Path
                        ) -> tuple[str, str, list[dict], int]:
    """:func:`finetune_member` in a :func:`run_jobs` worker, on the round's data read from
    disk; also returns how many updates its checkpoint already held (the caller logs only
    the rest)."""
    done = updates_done(stage_dir / f"{member_tag(name, i)}.ckpt")
    data, sample = round_data(cfg, data_dirs, dataset)
    return (*finetune_member(cfg, k, pretrained, path, i, name, what, data, sample, stage_dir),
            done)


def finetune_and_evaluate(cfg: Config, k: int, pretrained: dict, previous: list[str] | None,
                          name: str, what: str, data, uniform_sample, stage_dir: Path,
                          logger=None, data_dirs: list[str] | None = None,
                          dataset: str | None = None) -> dict:
    """One method of a round for every ensemble member: ``cfg.finetune_updates`` resumable
    updates (``name`` "simdist": dynamics only; "whole": the ablation), weights and a
    self-describing agent file saved per member, then the members' planner evaluated in
    the target. Member 0's files keep the single-model names (``simdist.pt``, ...).

    Slices of ``data`` (``[episodes, steps]``) come from ``uniform_sample``, or with
    ``cfg.finetune_priority_alpha > 0`` from :class:`PrioritisedSlices` ranked by the
    member's own consistency error (measured on every slice before the first update).
    Given ``data_dirs`` (the folders ``data`` was read from) and more than one member,
    the members finetune side by side in worker processes (:func:`member_jobs`)."""
    paths = member_paths(pretrained, previous)
    jobs, threads = member_jobs(cfg, len(paths))
    if jobs > 1 and data_dirs is not None:
        done = run_jobs([(finetune_member_job, (cfg, k, pretrained, path, i, name, what,
                                                data_dirs, dataset, stage_dir))
                         for i, path in enumerate(paths)], jobs, threads=threads)
        for i, (*_, history, before) in enumerate(done):
            log_trained(logger, f"round_{k + 1}/{member_tag(name, i)}", history, before)
    else:
        done = [finetune_member(cfg, k, pretrained, path, i, name, what, data, uniform_sample,
                                stage_dir, logger) for i, path in enumerate(paths)]
    return method_results(cfg, pretrained, name, done)


def method_results(cfg: Config, pretrained: dict, name: str, done: list[tuple]) -> dict:
    """A finetuned method's round entries from its members' ``(weights, agent file,
    history)``, its planner evaluated in the target."""
    saved = [d[0] for d in done]
    agent_files = [d[1] for d in done]
    return {name: saved[0], f"{name}_members": saved,
            f"{name}_agent": agent_files[0], f"{name}_member_agents": agent_files,
            f"{name}_eval": evaluate_planner(cfg, planning_agent(cfg, pretrained, saved),
                                             cfg.target)[0],
            f"{name}_loss": mean_metrics(done[0][2])}


def method_job(cfg: Config, k: int, pretrained: dict, path: str, name: str, what: str,
               data_dirs: list[str], dataset: str | None, stage_dir: Path
               ) -> tuple[dict, list[dict], int]:
    """One finetuned method of a one-model round in a :func:`run_jobs` worker: the model
    at ``path`` finetuned on the round's data read from disk, then evaluated. Returns its
    round entries, its history and how many updates its checkpoint already held."""
    done = updates_done(stage_dir / f"{name}.ckpt")
    data, sample = round_data(cfg, data_dirs, dataset)
    trained = finetune_member(cfg, k, pretrained, path, 0, name, what, data, sample, stage_dir)
    return method_results(cfg, pretrained, name, [trained]), trained[2], done


def previous_members(previous: dict, name: str) -> list[str]:
    """A finished round's weights of method ``name``, one per ensemble member (a round
    recorded before ensembles has one)."""
    return previous.get(f"{name}_members", [previous[name]])


def load_round_data(data_dirs: list[str]) -> TensorDict:
    """Every round's target data so far, ``[episodes, steps]``."""
    return torch.cat([load_memmap(Path(d)) for d in data_dirs], 0)


def round_data(cfg: Config, data_dirs: list[str], dataset: str | None):
    """Every round's target data so far (``[episodes, steps]``, read from ``data_dirs``)
    and the finetuning batch sampler over it; with ``cfg.finetune_sim_fraction > 0`` part
    of every batch comes from the pretraining ``dataset``."""
    data = load_round_data(data_dirs)
    sim_slices = cfg.finetune_sim_slices()
    buffer = as_slices(data, cfg.slice_len, cfg.batch_slices - sim_slices)
    sample = lambda: buffer.sample().reshape(-1, cfg.slice_len)  # noqa: E731
    if sim_slices:  # co-training: part of every batch from the pretraining dataset
        if dataset is None:
            raise ValueError("finetune_sim_fraction > 0 needs the pretraining dataset's path "
                             "(round_stage(dataset=...))")
        sim_buffer = load_dataset(dataset, cfg.slice_len, cfg.slice_len * sim_slices)
        sample = CoTrainingSlices(sample, lambda: sim_buffer.sample().reshape(-1, cfg.slice_len),
                                  keys=FINETUNE_KEYS)
    return data, sample


def round_stage(cfg: Config, k: int, pretrained: dict, expert_path: str, stage_dir: Path,
                previous: dict | None, logger=None, dataset: str | None = None) -> dict:
    """One round: collect with the current SimDist planner, finetune all methods, evaluate.

    ``dataset`` (the pretraining dataset's path) is read only when
    ``cfg.finetune_sim_fraction > 0``."""
    budget = round(cfg.budgets_min[k] * STEPS_PER_MINUTE)
    done_before = previous["target_steps"] if previous else 0
    data_dir = stage_dir / "data"
    previous_simdist = previous and previous_members(previous, "simdist")
    previous_whole = previous and previous_members(previous, "whole")
    if not data_dir.exists():  # save_memmap renames a complete folder into place
        fresh = collect_round_data(cfg, pretrained, previous_simdist, budget - done_before,
                                   seed=cfg.seed + 1000 * (k + 1))
        save_memmap(fresh, data_dir)
    data_dirs = [*(previous["data"] if previous else []), str(data_dir)]
    previous_sac = previous["sac"] if previous else None
    jobs, threads = stage_jobs(cfg, 3)
    simdist_paths = member_paths(pretrained, previous_simdist)
    if jobs > 1 and len(simdist_paths) == 1:
        # one model: SimDist, the ablation and SAC side by side, each in its own process
        methods = [(method_job, (cfg, k, pretrained, simdist_paths[0],
                                 "simdist", "finetune dynamics", data_dirs, dataset, stage_dir)),
                   (method_job, (cfg, k, pretrained, member_paths(pretrained, previous_whole)[0],
                                 "whole", "finetune whole model", data_dirs, dataset, stage_dir)),
                   (sac_job, (cfg, k, expert_path, previous_sac, data_dirs, stage_dir))]
        results = {"target_steps": load_round_data(data_dirs).numel(), "data": data_dirs}
        for tag, (entries, history, before) in zip(("simdist", "whole", "sac"),
                                                   run_jobs(methods, jobs, threads=threads)):
            log_trained(logger, f"round_{k + 1}/{tag}", history, before)
            results.update(entries)
        return results
    data, sample = round_data(cfg, data_dirs, dataset)
    results = {"target_steps": data.numel(), "data": data_dirs}

    # SimDist: dynamics only, continuing from the previous round's dynamics.
    results.update(finetune_and_evaluate(
        cfg, k, pretrained, previous_simdist, "simdist", "finetune dynamics", data, sample,
        stage_dir, logger, data_dirs, dataset))
    # Ablation: the whole world model on the same data, same number of updates.
    results.update(finetune_and_evaluate(
        cfg, k, pretrained, previous_whole, "whole", "finetune whole model", data, sample,
        stage_dir, logger, data_dirs, dataset))
    # Baseline: continue the expert's SAC on the same target data.
    results.update(sac_round(cfg, k, expert_path, previous_sac, data, stage_dir, logger)[0])
    return results


def sac_round(cfg: Config, k: int, expert_path: str, previous_sac: str | None, data,
              stage_dir: Path, logger=None) -> tuple[dict, list[dict]]:
    """The continued-SAC baseline of round ``k``: ``cfg.finetune_updates`` resumable
    updates on the round's ``data`` from the expert (or the previous round's SAC), then
    evaluated in the target. Returns its round entries and its history."""
    sac = OfflineSAC(Expert.load(expert_path),
                     OfflineSACConfig(batch_size=cfg.sac_batch_size, seed=cfg.seed))
    if previous_sac:
        sac.load_state_dict(load_checkpoint(previous_sac)["state"]["sac"])
    sac_buffer = sac.buffer(data)
    hist = train_resumable(sac.update, sac_buffer.sample, cfg.finetune_updates, {"sac": sac},
                           stage_dir / "sac.ckpt", desc=f"round {k + 1}: continue expert SAC",
                           seed=stage_seed(cfg.seed, f"round_{k + 1}/sac"),
                           logger=logger, log_prefix=f"round_{k + 1}/sac")
    return {"sac": str(stage_dir / "sac.ckpt"),
            "sac_eval": evaluate(cfg, cfg.target, sac.expert().deterministic()),
            "sac_loss": mean_metrics(hist)}, hist


def sac_job(cfg: Config, k: int, expert_path: str, previous_sac: str | None,
            data_dirs: list[str], stage_dir: Path) -> tuple[dict, list[dict], int]:
    """:func:`sac_round` in a :func:`run_jobs` worker, on the round's data read from disk;
    also returns how many updates its checkpoint already held."""
    done = updates_done(stage_dir / "sac.ckpt")
    return (*sac_round(cfg, k, expert_path, previous_sac, load_round_data(data_dirs),
                       stage_dir), done)


def probe_stage(cfg: Config, dataset: str, pretrained: dict, stage_dir: Path,
                logger=None) -> dict:
    """A decoder latent -> privileged state on frozen pretrained latents (for pictures).

    Dynamics-only finetuning leaves the encoder unchanged, so the probe stays valid for
    every SimDist round.
    """
    agent = load_agent(cfg, pretrained)
    buffer = load_dataset(dataset, cfg.slice_len, cfg.slice_len * cfg.batch_slices)
    state_dim = buffer[:]["state"].shape[-1]
    probe = StateDecoder(agent.world_model.latent_dim, state_dim, hidden=256,
                         layers=2).to(cfg.device)
    loss = ProbeLoss(agent.world_model.encode_sequence, probe,
                     with_actions=bool(agent.world_model.encoder.action_dim))
    optim = torch.optim.Adam(loss.trainable_parameters(), lr=1e-3)

    def update(batch):
        out = loss(batch.to(cfg.device))
        optim.zero_grad(set_to_none=True)
        out["loss_probe"].backward()
        optim.step()
        return {"loss_probe": out["loss_probe"].item()}

    history = train_resumable(update, lambda: buffer.sample().reshape(-1, cfg.slice_len),
                              cfg.probe_updates, {"probe": probe, "optim": optim},
                              stage_dir / "training.pt", desc="probe decoder",
                              seed=stage_seed(cfg.seed, "probe"), logger=logger,
                              log_prefix="probe")
    save_atomic(probe.state_dict(), stage_dir / "probe.pt")
    return {"path": str(stage_dir / "probe.pt"), "state_dim": state_dim,
            "loss": mean_metrics(history)}


def pretrained_latent_dim(agent: SimDistAgent) -> int:
    """One member's latent size (the probe's input)."""
    wm = agent.world_model
    return wm.members[0].latent_dim if isinstance(wm, WorldModelEnsemble) else wm.latent_dim


class FirstMemberProbe(torch.nn.Module):
    """A latent -> state probe trained on member 0, applied to an (ensemble) latent."""

    def __init__(self, probe: torch.nn.Module, latent_dim: int):
        super().__init__()
        self.probe, self.latent_dim = probe, latent_dim

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        return self.probe(latent[..., :self.latent_dim])


def zero_shot_job(cfg: Config, pretrained: dict, domain: str) -> dict:
    """The pretrained planner evaluated in ``domain`` (a :func:`run_jobs` call)."""
    return evaluate_planner(cfg, planning_agent(cfg, pretrained), domain)[0]


def recording_stage(cfg: Config, pretrained: dict, probe: dict, final: dict, out: Path) -> dict:
    """rerun recordings of one target episode before and after dynamics finetuning (side
    by side, :func:`stage_jobs`)."""
    labels = (("before", None), ("after", previous_members(final, "simdist")))
    jobs, threads = stage_jobs(cfg, len(labels))
    paths = {}
    for recorded in run_jobs([(recording_job, (cfg, pretrained, probe, weights, label, out))
                              for label, weights in labels], jobs, threads=threads):
        paths.update(recorded)
    return paths


def recording_job(cfg: Config, pretrained: dict, probe: dict, weights: list[str] | None,
                  label: str, out: Path) -> dict:
    """One recording of :func:`recording_stage`: the planner on ``weights`` (None: the
    pretrained model) for one target episode, to ``rerun_{label}.rrd`` and an MP4."""
    agent = planning_agent(cfg, pretrained, weights)
    # the probe reads member 0's latent (the first slice of an ensemble's)
    probe_net = StateDecoder(pretrained_latent_dim(agent), probe["state_dim"], hidden=256,
                             layers=2)
    probe_net.load_state_dict(load_checkpoint(probe["path"]))
    probe_net = FirstMemberProbe(probe_net, pretrained_latent_dim(agent)).to(cfg.device)
    env = locomotion_env(get_target(cfg.target), 1, cfg.episode_steps, cfg.seed + 10_000,
                         task=cfg.task, upright_power=cfg.reward_upright_power,
                         primers=[agent.make_primer(cfg.planner().latency_compensation)])
    spec = env.action_spec
    policy = agent.policy(spec.space.low[0], spec.space.high[0], cfg.planner(), seed=cfg.seed)
    # the same episode also as a video, for readers without a rerun viewer (when an MP4
    # encoder is installed: run() warned before any work otherwise)
    video = out / f"planner_{label}_finetuning.mp4" if video_backend_available() else None
    path = record_planning_episode(env, policy, probe_net, str(out / f"rerun_{label}.rrd"),
                                   cfg.episode_steps, application_id=f"simdist_{label}_finetuning",
                                   video_path=video)
    env.close()
    return {label: path, **({f"video_{label}": str(video)} if video else {})}


# -- the recipe -------------------------------------------------------------------------
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
    results = collect_results(cfg, expert_zero_shot, planner_zero_shot, rounds)
    runner.close()
    print_table(results, get_target(cfg.target).name, reference=SIMDIST)
    print("\nstage timings: " + ", ".join(f"{k} {v:.0f} s" for k, v in runner.timings.items()))
    summary = {"config": dataclasses.asdict(cfg), "expert": expert, "dataset": dataset,
               "pretrain": pretrained, "expert_zero_shot": expert_zero_shot,
               "planner_zero_shot": planner_zero_shot, "probe": probe,
               "recordings": recordings, "curves": results, "timings_s": runner.timings,
               "torch_threads": torch.get_num_threads(), "precision": precision,
               "machine": machine}
    write_json_atomic(out / "results.json", summary)
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
    later = ["zero_shot", *(f"round_{k + 1}" for k in range(len(cfg.budgets_min)))]
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
    write_json_atomic(out / "results.json", summary)
    plot_results(curves, get_target(cfg.target).name, out / "forward_progress.png")
    print(f"wrote {out / 'results.json'} and {out / 'forward_progress.png'}")
    return summary


def main(argv=None):
    cfg, _ = parse_config(Config, PRESETS, argv, description=__doc__.splitlines()[0],
                          prog="simdist_quadruped.py")
    if not cfg.retrain_expert and not resolve_expert(cfg.expert).exists():  # before any work
        raise SystemExit(f"simdist_quadruped.py: error: expert: no checkpoint at {cfg.expert}: "
                         "train one with `python recipes/train_expert.py` or pass "
                         "--retrain-expert")
    with exit_on_folder_errors("simdist_quadruped.py"):
        return run_seeds(cfg) if cfg.seeds else run(cfg)


def collect_results(cfg, expert_zero_shot, planner_zero_shot, rounds) -> dict:
    """Per method: data budget (minutes) -> evaluation stats in the target."""
    minutes = [0.0] + [r["target_steps"] / STEPS_PER_MINUTE for r in rounds]
    zero = planner_zero_shot[cfg.target]
    expert = expert_zero_shot[cfg.target]
    return {
        "minutes": minutes,
        "planner_in_sim": planner_zero_shot["sim"],
        "expert (zero-shot)": [expert] * len(minutes),
        SIMDIST: [zero] + [r["simdist_eval"] for r in rounds],
        "ablation: finetune whole model": [zero] + [r["whole_eval"] for r in rounds],
        "baseline: continue expert SAC": [expert] + [r["sac_eval"] for r in rounds],
    }


def cli() -> None:
    """The ``simdist-quadruped`` console script: :func:`main` on ``sys.argv``, exit status 0."""
    main()


if __name__ == "__main__":
    main()
