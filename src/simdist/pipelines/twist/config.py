"""The TWIST control-suite pipeline's configuration: one field per command-line flag, the named
presets, and the method and baseline names of its table.
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import simdist  # noqa: F401  (headless GL set-up before dm_control)
from simdist.agents import DreamerConfig, TwistConfig
from simdist.envs import TASKS, VisualRandomisation
from simdist.modules import RSSM_SIZES, PixelEncoder
from simdist.pipelines import OnlineConfig, control_env
from simdist.pipelines.experiment_log import LOGGERS
from simdist.utils import resolve_device
from simdist.utils.cli import check, check_builds, check_positive
from simdist.utils.stages import ABSENT_MEANS

TWIST = "TWIST (student)"
# stage suffix -> (table name, TwistConfig overrides): the paper's two ablations
STUDENTS = {"twist": (TWIST, {}),
            "no_imagined": ("TWIST w/o imagined alignment", {"imagined": False}),
            "no_noise": ("TWIST w/o action noise", {"action_noise_std": 0.0})}
# the same stages' table names where the student sees through a readout (privileged state
# regression): another method than TWIST, so never under TWIST's name
READOUT_STUDENTS = {"twist": "Readout student (privileged state regression)",
                    "no_imagined": "Readout student w/o imagined alignment",
                    "no_noise": "Readout student w/o action noise"}
ASYMMETRIC_SAC = ("asymmetric_sac", "Asymmetric SAC + DR")  # (stage suffix, table name)
# ReferencePolicy kind -> table name: blind policies that say what a return is worth
REFERENCES = {"zero": "zero action (reference)", "uniform": "random actions (reference)"}
# stage suffix -> (table name, visual randomisation while training)
PIXEL_DREAMERS = {"dreamer_dr": ("Dreamer from pixels + DR", VisualRandomisation.training()),
                  "dreamer_no_dr": ("Dreamer from pixels, no DR", None),
                  # TWIST's "Dreamer State Recon.": pixels in (with DR), the decoder
                  # reconstructs the privileged state instead of the image
                  "dreamer_state_recon": ("Dreamer State Recon. + DR",
                                          VisualRandomisation.training())}


@dataclass
class Config:
    """Every setting of the TWIST control-suite pipeline; presets override fields.

    Every field is a command-line flag (``--kebab-case``) and the whole config is saved as
    ``config.json`` beside the run. A value that cannot work is refused before any stage
    runs (:meth:`__post_init__`). Why each default is what it is: ``docs/twist_defaults.md``.

    Examples:
        >>> cfg = Config(**PRESETS["tiny"], students=["twist"])
        >>> cfg.tasks, cfg.jobs <= 2
        (['cartpole-balance'], True)
    """

    # -- tasks and budget

    tasks: list[str] = field(default_factory=lambda: ["cartpole-balance"])  # control-suite tasks
    seeds: list[int] = field(default_factory=lambda: [0])  # one chain of stages per task and seed
    model_size: str = "compact"  # RSSM size of teacher, student and pixel Dreamers
    # environment steps of the teacher and of every online baseline (the same for all)
    env_steps: int = 12000
    prefill_steps: int = 1000  # random-action steps before the first update
    train_every: int = 2  # teacher: one update per this many agent steps
    # pixel Dreamers: one update per this many agent steps (an update costs ~4x the
    # teacher's on a CPU)
    pixel_train_every: int = 20
    episode_steps: int = 500  # steps per training episode
    slice_len: int = 50  # online Dreamers: steps per training slice
    slices: int = 16  # online Dreamers: slices per update
    horizon: int = 15  # imagination horizon (actor-critic and imagined alignment)
    imagination_starts: int = 256  # per update, for the actor-critic and Eq. 4
    actor_lr: float = 3e-4  # actor learning rate (teacher and pixel Dreamers)
    critic_lr: float = 3e-4  # critic learning rate (teacher and pixel Dreamers)
    # the Dreamers' actor returns: "none" (DreamerV2) or "percentile" (DreamerV3)
    return_normalisation: str = "none"

    # -- teacher

    # keep the teacher after each of its last N training episodes and deploy the one with
    # the best validation return (0: the last weights, as TWIST)
    teacher_snapshots: int = 10
    teacher_select_episodes: int = 10  # validation episodes per teacher snapshot
    # the teacher's actor learns on latents with Gaussian noise of this many feature stds
    # (0: TWIST's teacher)
    teacher_actor_noise: float = 0.0
    teacher_standardise: bool = False  # standardise the teacher's state reconstruction target
    # render D's images: "auto" only when a student reads them, "always" keeps them
    teacher_pixels: str = "auto"
    # D's images also get a camera-pose draw every step (not in TWIST's training DR)
    train_camera: bool = False
    # the task model's camera for every pixel method (None: the task's own, as TWIST)
    camera_id: int | None = None

    # -- student (TWIST: slices of 50, imagination horizon 15, action noise 0.3)

    student_updates: int = 300  # student distillation updates on the teacher's data
    student_slice_len: int = 50  # student: steps per slice
    student_slices: int = 8  # student: slices per update
    action_noise_std: float = 0.3  # TWIST's action noise in the imagined rollouts
    student_depth: int | None = None  # CNN depth (None: the model size's)
    student_norm: str | None = "layer"  # None or "layer" (PixelEncoder.norm)
    student_input_norm: str = "image"  # or "fixed" (PixelEncoder.input_norm)
    student_shift_pad: int = 4  # DrQ random shift in pixels, 0: none
    student_shift_per: str = "sequence"  # one draw per slice, or "frame"
    student_rotate_deg: float = 0.0  # random in-plane rotation in degrees
    student_arch: str = "dreamer"  # "dreamer" CNN or "keypoints" (spatial softmax)
    student_lr: float = 3e-4  # student learning rate

    # -- readout student (privileged state regression; not the paper's TWIST)

    # the student's eyes: "none", TWIST's CNN student (Eq. 3 + Eq. 4 only); "auto", the
    # readout student where the task has a committed readout for the camera; or a readout file
    student_readout: str = field(default="none", metadata={ABSENT_MEANS: "auto"})
    readout_student_updates: int = 1800  # readout student: distillation updates
    readout_student_lr: float = 1e-3  # readout student: learning rate
    readout_student_slices: int = 16  # readout student: slices per update
    # Gaussian noise on the readings in every update, in readout stds (0: none)
    readout_student_reading_noise: float = 0.0
    # what its state encoder reads in training: "positions" (D's exact values) or
    # "readings" (the readout's readings of D's images)
    readout_student_inputs: str = "positions"
    # which of D's steps it trains on, one candidate each: "domain" (inside the readout's
    # fitted domain) or "all"
    readout_student_states: list[str] = field(default_factory=lambda: ["all", "domain"])
    # more candidates, distilled from the teacher's last snapshot ([]: none)
    student_last_teacher_states: list[str] = field(default_factory=lambda: ["all"])
    student_select_episodes: int = 10  # validation episodes per candidate student

    # -- baselines

    # Asymmetric SAC (pixel actor, state critic): one update of sac_batch transitions per
    # sac_train_every agent steps
    sac_train_every: int = 4
    sac_batch: int = 128
    sac_frames: int = field(default=3, metadata={ABSENT_MEANS: 1})  # stacked images the actor reads
    sac_n_step: int = field(default=3, metadata={ABSENT_MEANS: 1})  # the critic's n-step return
    sac_tau: float = field(default=0.02, metadata={ABSENT_MEANS: 0.005})  # target Polyak rate
    # pixel Dreamers' actor: "tanh_normal" (the teacher's) or "trunc_normal" (DreamerV2)
    pixel_actor_distribution: str = "tanh_normal"
    # pixel Dreamers' exploration: "noise" (the teacher's) or "sample" (DreamerV2)
    pixel_exploration: str = "noise"
    # pixel Dreamers' actor gradient: "dynamics" (the teacher's) or "reinforce" (DreamerV3)
    pixel_actor_gradient: str = "dynamics"
    pixel_reward_scale: float = 1.0  # pixel Dreamers' reward weight (the teacher's is 1)
    pixel_encoder: str = "dreamer"  # pixel Dreamers' image encoder: "dreamer" or "keypoints"
    # Dreamer State Recon.'s state target standardised per dimension
    state_recon_standardise: bool = field(default=True, metadata={ABSENT_MEANS: False})

    # -- evaluation on held-out scenes

    eval_episodes: int = 10  # evaluation episodes per method and seed
    eval_steps: int = 500  # steps per evaluation episode

    # -- outputs and resources (not part of the results)

    record: bool = True  # a rerun recording of one student episode
    output_dir: str = "outputs/twist_dmc"  # stages, results and plots go here
    # where the networks train and act: cpu, cuda or auto (envs and rendering stay on the CPU)
    device: str = "cpu"
    # False: only the teacher chain (teacher, Oracle, references, students); a later run
    # with True into the same folder adds the baselines
    baselines: bool = True
    # which of TWIST and its ablations to distil (twist, no_imagined, no_noise)
    students: list[str] = field(default_factory=lambda: list(STUDENTS))
    jobs: int = min(2, os.cpu_count() or 1)  # chains run side by side in this many processes
    # scalar logs under <output_dir>/logs: csv, tensorboard, wandb (offline) or none
    logger: str = "csv"

    def __post_init__(self):
        control = sorted(t for t in TASKS if not TASKS[t].is_robot)
        unknown = [t for t in self.tasks if t not in control]
        check(self.tasks and not unknown, "tasks",
              f"unknown control-suite tasks {unknown or self.tasks}; valid: {control}")
        check(self.seeds and len(set(self.seeds)) == len(self.seeds), "seeds",
              f"need distinct seeds, got {self.seeds}")
        check(self.model_size in RSSM_SIZES, "model_size",
              f"unknown size {self.model_size!r}; valid: {sorted(RSSM_SIZES)}")
        check_positive(self, "env_steps", "train_every", "pixel_train_every", "episode_steps",
                       "slice_len", "slices", "student_slice_len", "student_slices", "horizon",
                       "sac_train_every", "sac_batch", "sac_frames", "sac_n_step", "sac_tau",
                       "imagination_starts", "eval_episodes", "eval_steps", "student_lr",
                       "actor_lr", "critic_lr", "jobs", "teacher_select_episodes")
        unknown = [name for name in self.students if name not in STUDENTS]
        check(self.students and not unknown and len(set(self.students)) == len(self.students),
              "students", f"need distinct names from {list(STUDENTS)}, got {self.students}")
        check(not self.record or "twist" in self.students, "students",
              "the recording shows the TWIST student: add 'twist' or pass --no-record")
        for flag in ("train_camera", "baselines"):
            check(isinstance(getattr(self, flag), bool), flag,
                  f"must be true or false, got {getattr(self, flag)!r}")
        check(self.student_readout in ("auto", "none") or _readout_file_ok(self.student_readout),
              "student_readout", f"must be 'auto', 'none' or a readout file (.pt with its "
              f".json beside it), got {self.student_readout!r}")
        check_positive(self, "readout_student_lr", "readout_student_slices")
        check_positive(self, "prefill_steps", "student_updates", "action_noise_std",
                       "readout_student_updates", "readout_student_reading_noise",
                       "teacher_actor_noise", "teacher_snapshots",
                       "student_shift_pad", "student_rotate_deg", allow_zero=True)
        check(self.camera_id is None or self.camera_id >= 0, "camera_id",
              f"must be >= 0 or None, got {self.camera_id}")
        check(self.student_depth is None or self.student_depth > 0, "student_depth",
              f"must be > 0 or None, got {self.student_depth}")
        check(self.student_norm in PixelEncoder.NORMS, "student_norm",
              f"must be one of {PixelEncoder.NORMS}, got {self.student_norm!r}")
        check(self.student_input_norm in PixelEncoder.INPUT_NORMS, "student_input_norm",
              f"must be one of {PixelEncoder.INPUT_NORMS}, got {self.student_input_norm!r}")
        check(self.student_arch in PixelEncoder.ARCHS, "student_arch",
              f"must be one of {PixelEncoder.ARCHS}, got {self.student_arch!r}")
        check(self.readout_student_inputs in ("readings", "positions"),
              "readout_student_inputs",
              f"must be 'readings' or 'positions', got {self.readout_student_inputs!r}")
        states = tuple(self.readout_student_states)
        check(len(states) in (1, 2) and len(set(states)) == len(states)
              and set(states) <= {"domain", "all"}, "readout_student_states",
              f"must be one or two distinct of 'domain', 'all', got {states!r}")
        check("all" not in states or self.readout_student_inputs == "positions",
              "readout_student_states",
              "'all' needs readout_student_inputs='positions' (outside its fitted domain the "
              "readout's readings are extrapolations, not something to train on): pass "
              "--readout-student-states domain --student-last-teacher-states domain with "
              "readings")
        last = tuple(self.student_last_teacher_states)
        check(len(set(last)) == len(last) and set(last) <= {"domain", "all"},
              "student_last_teacher_states",
              f"must be distinct entries of 'domain', 'all', got {last!r}")
        check("all" not in last or self.readout_student_inputs == "positions",
              "student_last_teacher_states",
              "'all' needs readout_student_inputs='positions' (pass "
              "--student-last-teacher-states domain with readings, or none)")
        check(self.teacher_pixels in ("auto", "always"), "teacher_pixels",
              f"must be 'auto' or 'always', got {self.teacher_pixels!r}")
        check(self.student_select_episodes > 0, "student_select_episodes",
              f"must be > 0, got {self.student_select_episodes}")
        check(self.student_shift_per in ("sequence", "frame"), "student_shift_per",
              f"must be 'sequence' or 'frame', got {self.student_shift_per!r}")
        check_builds("online budget", self.online)
        check(self.teacher_snapshots <= self.online().episodes, "teacher_snapshots",
              f"the teacher trains {self.online().episodes} episodes, so at most that many "
              f"snapshots, got {self.teacher_snapshots} (lower --teacher-snapshots with "
              f"--env-steps)")
        check_builds("dreamer", self.dreamer)
        check_builds("pixel_actor_distribution / pixel_exploration / pixel_actor_gradient / "
                     "pixel_reward_scale / pixel_encoder", self.pixel_dreamer)
        check_builds("device", resolve_device, self.device)
        check(self.logger in LOGGERS, "logger", f"must be one of {LOGGERS}, got {self.logger!r}")

    def online(self, pixels: bool = False) -> OnlineConfig:
        return OnlineConfig(env_steps=self.env_steps, prefill_steps=self.prefill_steps,
                            train_every=self.pixel_train_every if pixels else self.train_every,
                            episode_steps=self.episode_steps, slice_len=self.slice_len,
                            slices=self.slices)

    def sac_online(self) -> OnlineConfig:
        """The Asymmetric SAC's budget: slices of ``sac_frames + sac_n_step`` steps give
        one transition each."""
        return dataclasses.replace(self.online(pixels=True), train_every=self.sac_train_every,
                                   slice_len=self.sac_frames + self.sac_n_step,
                                   slices=self.sac_batch)

    def dreamer(self) -> DreamerConfig:
        return DreamerConfig(size=self.model_size, horizon=self.horizon,
                             imagination_starts=self.imagination_starts,
                             actor_lr=self.actor_lr, critic_lr=self.critic_lr,
                             return_normalisation=self.return_normalisation)

    def pixel_dreamer(self) -> DreamerConfig:
        """The pixel Dreamers' config: the teacher's, with their own actor form."""
        return dataclasses.replace(self.dreamer(),
                                   actor_distribution=self.pixel_actor_distribution,
                                   exploration=self.pixel_exploration,
                                   actor_gradient=self.pixel_actor_gradient,
                                   reward_scale=self.pixel_reward_scale,
                                   encoder=self.pixel_encoder,
                                   standardise_reconstruction=self.state_recon_standardise)


PRESETS = {
    "default": {},
    "tiny": {"model_size": "tiny", "env_steps": 40, "prefill_steps": 20, "train_every": 10,
             "teacher_snapshots": 2,
             "pixel_train_every": 10, "sac_train_every": 10, "sac_batch": 4,
             "readout_student_updates": 3, "readout_student_slices": 2,
             "episode_steps": 20, "slice_len": 8, "slices": 2, "student_updates": 3,
             "student_slice_len": 8, "student_slices": 2, "horizon": 3,
             "imagination_starts": 8, "eval_episodes": 2, "eval_steps": 10},
    "paper": {"tasks": ["ball_in_cup-catch", "cartpole-balance", "cheetah-run",
                        "hopper-stand", "walker-walk", "finger-turn_easy"],
              "seeds": [0, 1, 2], "model_size": "paper", "env_steps": 500_000,
              "prefill_steps": 5000, "train_every": 5, "pixel_train_every": 5, "slice_len": 50,
              "slices": 16, "actor_lr": 8e-5, "critic_lr": 8e-5,
              "student_updates": 100_000, "student_slices": 16, "imagination_starts": 800,
              "readout_student_updates": 100_000,
              "eval_episodes": 10},
}


# -- stages -----------------------------------------------------------------------------
# training camera jitter when Config.train_camera: 1.5x the evaluation's half-widths
# (VisualRandomisation defaults, +-0.1 m and +-5 deg): covers the test poses with a margin
# without being fitted to them
TRAIN_CAMERA_JITTER = {
    "camera_position_jitter": round(1.5 * VisualRandomisation.camera_position_jitter, 6),
    "camera_angle_jitter_deg": round(1.5 * VisualRandomisation.camera_angle_jitter_deg, 6)}


def saved_config(outputs: str | os.PathLike, preset: str = "default") -> Config:
    """The config of a finished run in ``outputs`` (its ``config.json``), fields this code
    no longer has dropped and fields added since at ``preset``'s values (or at what a
    folder without them was made with, their ``ABSENT_MEANS``); without a
    ``config.json``, ``preset``'s config."""
    saved = Path(outputs) / "config.json"
    base = dataclasses.replace(Config(), **PRESETS[preset])
    if not saved.exists():
        return base
    known = {f.name for f in dataclasses.fields(Config)}
    values = {k: v for k, v in json.loads(saved.read_text()).items() if k in known}
    absent = {f.name: f.metadata[ABSENT_MEANS] for f in dataclasses.fields(Config)
              if ABSENT_MEANS in f.metadata and f.name not in values}
    return dataclasses.replace(base, **{**absent, **values})


def training_visual(cfg: Config) -> VisualRandomisation:
    """The randomisation under which the teacher stage records D's images."""
    if cfg.train_camera:
        return VisualRandomisation.training(camera=True, **TRAIN_CAMERA_JITTER)
    return VisualRandomisation.training()


def state_dim(task: str) -> int:
    env = control_env(task, 0)
    try:
        return env.observation_spec["state"].shape[-1], env.action_spec.shape[-1]
    finally:
        env.close()


def twist_config(cfg: Config, overrides: dict) -> TwistConfig:
    """The recipe's student settings, with an ablation's ``overrides`` on top."""
    config = TwistConfig(horizon=cfg.horizon, action_noise_std=cfg.action_noise_std,
                         max_imagination_starts=cfg.imagination_starts,
                         shift_pad=cfg.student_shift_pad, shift_per=cfg.student_shift_per,
                         rotate_deg=cfg.student_rotate_deg, lr=cfg.student_lr)
    return dataclasses.replace(config, **overrides)


#: the committed readouts, one per task (``<task>.pt`` and ``<task>.json``)
# the committed readouts are package data (src/simdist/checkpoints/twist_readout)
READOUT_DIR = Path(__file__).resolve().parents[2] / "checkpoints" / "twist_readout"


def _readout_file_ok(path: str) -> bool:
    return Path(path).is_file() and Path(path).with_suffix(".json").is_file()


# -- the recipe -------------------------------------------------------------------------
#: settings only the Asymmetric SAC baseline's stage reads
SAC_FIELDS = ("sac_train_every", "sac_batch", "sac_frames", "sac_n_step", "sac_tau")
#: settings only the baselines' stages read (the SAC's and Dreamer State Recon.'s)
BASELINE_FIELDS = (*SAC_FIELDS, "state_recon_standardise")
