"""The SimDist quadruped pipeline's configuration: one field per command-line flag, and the
named presets.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field

import simdist  # noqa: F401  (headless GL set-up before dm_control)
from simdist.data import DatasetConfig, PerturbationSchedule
from simdist.envs import TASKS, Layout, get_target, make_env
from simdist.experts import SACExpertConfig
from simdist.modules import SIMDIST_SIZES
from simdist.modules.planner import PlannerConfig
from simdist.modules.simdist_model import DYNAMICS_RESIDUALS
from simdist.objectives.simdist_pretrain import CONSISTENCY_KINDS
from simdist.pipelines.experiment_log import LOGGERS
from simdist.utils import resolve_device
from simdist.utils.cli import check, check_builds, check_positive
from simdist.utils.precision import PRECISIONS
from simdist.utils.stages import ABSENT_MEANS

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
    """Every setting of the SimDist quadruped pipeline; presets override fields.

    Every field is a command-line flag (``--kebab-case``) and the whole config is saved as
    ``config.json`` beside the run. A value that cannot work is refused before any stage
    runs (:meth:`__post_init__`). Why each default is what it is: ``docs/simdist_defaults.md``.

    Examples:
        >>> cfg = Config(**PRESETS["tiny"], target="foam")
        >>> cfg.expert_targets
        ['sim', 'slippery_slope', 'foam']
    """

    # -- domains and evaluation

    task: str = "quadruped-flat"  # evaluation task; a target sets its own slope
    data_task: str = "quadruped-terrain"  # expert retraining and the dataset: mixed slopes
    # deployment target: a name in simdist.envs.TARGETS, a JSON object of TargetDomain
    # fields ('{"name": "icy", "friction": 0.4}') or the path of a .json file holding one
    target: str = "slippery_slope"
    # domains the expert is evaluated in zero-shot (the target is added if missing)
    expert_targets: list[str] = field(default_factory=lambda: [
        "sim", "slippery_slope", "foam", "payload", "weak_motors"])
    episodes: int = 32  # evaluation episodes per point (worlds stepped at once)
    episode_steps: int = 250  # steps per episode (5 s at 50 Hz)
    # episodes of the planner with the simulator as its dynamics in the target (the
    # frozen parts' ceiling; 0: skip it: ~0.6 s per world and step on one CPU core)
    ceiling_episodes: int = field(default=0, metadata={ABSENT_MEANS: 0})
    seed: int = 0  # seed of every stage of a single run
    # several seeds, each into <output_dir>/seed_<N>, and one table over them
    seeds: list[int] = field(default_factory=list)

    # -- expert

    expert: str = DEFAULT_EXPERT  # expert checkpoint (SAC, recipes/train_expert.py)
    retrain_expert: bool = False  # retrain the expert on data_task (hours on 2 CPU cores)
    expert_frames: int = SACExpertConfig.total_frames  # SAC frames when retraining

    # -- dataset

    dataset_episodes: int = 1536  # perturbed-expert episodes in the pretraining dataset
    dataset_shard_episodes: int = 32  # episodes per shard (the unit of resume and workers)
    # processes stepping each shard's worlds (changes no result)
    dataset_workers: int = 1
    # std of Gaussian action noise outside the perturbation bursts (0: the reference)
    dataset_dither_std: float = 0.0
    # exponent of the reward's upright term (the committed expert was trained with 1)
    reward_upright_power: float = 1.0

    # -- world model

    model_size: str = "wide"  # simdist.modules.SIMDIST_SIZES: tiny, small, wide, paper
    # observation steps the encoder reads (0: the size's own; the reference: 25)
    model_history: int = 0
    model_dynamics_hidden: int = 0  # width of the dynamics MLP (0: the size's own)
    # latent size (0: the size's own), a multiple of SimNorm's group of 8
    model_latent_dim: int = field(default=256, metadata={ABSENT_MEANS: 0})
    # the encoder also reads the previous action (the latent carries actions in flight)
    model_previous_action: bool = field(default=True, metadata={ABSENT_MEANS: False})
    # the dynamics' step: "logit" norm(log z + f) or "additive" norm(z + f)
    model_dynamics_residual: str = field(default="logit", metadata={ABSENT_MEANS: "additive"})
    # the policy prior's box: the task's per-joint action bounds (else [-1, 1])
    model_prior_bounds: bool = False
    # steps of latent rollout in the pretraining and finetuning losses
    model_horizon: int = 5
    # robot-observation groups the encoder does not read (names from the task's
    # observation layout, e.g. toe_force); [] reads everything
    model_ignored_observations: list[str] = field(default_factory=list)
    # world models pretrained on the same dataset and planned with together (K x the cost)
    ensemble_size: int = 1
    # with ensemble_size > 1: one encoder and one set of heads, K dynamics
    ensemble_shared_encoder: bool = False

    # -- pretraining

    pretrain_updates: int = 12000  # world-model updates on the dataset
    slice_len: int = 16  # steps per training slice
    batch_slices: int = 32  # slices per update
    # weight of the value regression (~(1 - gamma)^2: the labels sum up to 100 rewards)
    value_weight: float = 1e-3
    # training arithmetic: none (float32), bfloat16 (autocast), auto (bfloat16 if native)
    mixed_precision: str = field(default="auto", metadata={ABSENT_MEANS: "none"})
    heldout_episodes: int = 32  # fresh-seed episodes for the latent prediction diagnostic

    # -- planner (latent MPPI)

    planner_horizon: int = 20  # planning horizon in steps (20 = 0.4 s at 50 Hz)
    planner_samples: int = 64  # action sequences per iteration
    planner_iterations: int = 3  # refinement iterations per step
    planner_elites: int = 8  # elites kept per iteration
    planner_policy_fraction: float = 0.9  # share of the samples proposed by the policy prior
    planner_policy_noise: float = 0.3  # std of the noise on the prior's proposals
    # steps at the start of the plan on which the proposals carry that noise (0: all)
    planner_policy_noise_steps: int = 0
    # lambda of the values read along a plan (1: the terminal value alone, the reference)
    planner_value_lambda: float = field(default=0.95, metadata={ABSENT_MEANS: 1.0})
    # the lambda-return reads the value at every k-th predicted step only
    planner_value_every: int = field(default=2, metadata={ABSENT_MEANS: 1})
    planner_latency_compensation: int = 0  # steps of action delay the planner compensates
    # commands the prior's proposals are also drawn for (empty: the episode's own only)
    planner_proposal_commands: tuple[float, ...] = ()
    # arithmetic of the candidate rollouts: "none" (float32), "bfloat16" or "auto"
    planner_precision: str = field(default="auto", metadata={ABSENT_MEANS: "none"})

    # -- target rounds (collection and finetuning)

    # cumulative minutes of 50 Hz target data after each round
    budgets_min: list[float] = field(default_factory=lambda: [2.0, 8.0])
    collect_episodes: int = 12  # worlds stepped at once while collecting
    # the collecting planner's search, where it differs from the evaluated one (0: same)
    collect_planner_samples: int = field(default=48, metadata={ABSENT_MEANS: 0})
    collect_planner_iterations: int = field(default=2, metadata={ABSENT_MEANS: 0})
    collect_planner_elites: int = field(default=6, metadata={ABSENT_MEANS: 0})
    # collection only: a robot on its back starts a new episode (evaluation never does)
    collect_reset_upside_down: bool = False
    finetune_updates: int = 1000  # per round, for every method (same data, same updates)
    finetune_lr: float = 1e-4  # dynamics-only (and whole-model ablation) learning rate
    # finetuning terms through the frozen reward and value heads (0: the reference)
    finetune_reward_weight: float = 0.0
    finetune_value_weight: float = 0.0
    # finetuning consistency: squared (the reference) or kl (per SimNorm group)
    finetune_consistency: str = field(default="squared", metadata={ABSENT_MEANS: "squared"})
    # prioritised finetuning slices: p ~ error^alpha, weights ^beta (0: uniform)
    finetune_priority_alpha: float = 0.0
    finetune_priority_beta: float = 0.4
    # share of each finetuning batch from the simulation dataset (0: the reference)
    finetune_sim_fraction: float = field(default=0.0, metadata={ABSENT_MEANS: 0.0})
    sac_batch_size: int = 256  # continued-SAC baseline batch size

    # -- outputs and resources (not part of the results)

    probe_updates: int = 1000  # latent -> state probe, for the rerun recordings only
    # rerun recordings and videos of a target episode before and after finetuning
    record: bool = True
    output_dir: str = "outputs/simdist_quadruped"  # stages, results and plots go here
    # where the world model trains and plans: cpu, cuda or auto (envs stay on the CPU)
    device: str = "cpu"
    # scalar logs under <output_dir>/logs: csv, tensorboard, wandb (offline) or none
    logger: str = "csv"
    # torch CPU threads (0: one per core); float sums differ slightly with the count
    threads: int = 0
    # processes for a stage's independent parts (0: as the threads allow; 1: in turn)
    jobs: int = 0
    # processes training the ensemble members (0: as the threads allow; 1: in turn)
    ensemble_jobs: int = 0

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
        check_positive(self, "ceiling_episodes", allow_zero=True)
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


def dataset_config(cfg: Config) -> DatasetConfig:
    return DatasetConfig(task=cfg.data_task, episodes=cfg.dataset_episodes,
                         episode_steps=cfg.episode_steps, shard_episodes=cfg.dataset_shard_episodes,
                         num_workers=cfg.dataset_workers, seed=cfg.seed,
                         schedule=PerturbationSchedule(dither_std=cfg.dataset_dither_std),
                         upright_power=cfg.reward_upright_power)


@functools.lru_cache(maxsize=None)
def observation_layout(task: str) -> Layout:
    """The robot observation's named groups for ``task`` (read off one world)."""
    env = make_env(task, seed=0)
    try:
        return env.observation_layout
    finally:
        env.close()
