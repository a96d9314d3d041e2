"""TWIST on the control suite: distil an image student from a state teacher, with baselines.

Per task and seed (each stage checkpointed under ``--output-dir``; rerunning skips
finished stages and a killed stage resumes from its last checkpoint):

1. ``teacher``: Dreamer on privileged state, collecting online; every step also records
   the domain-randomised image (randomised every step), building ``D = {(s, o, a, r)}``.
2. ``oracle``: the teacher itself, evaluated (the upper bound); ``references``: zero and
   uniform random actions on the same seeds, what a return is worth on the task (doing
   nothing scores 750 on cartpole-balance, where the pole swings back past upright).
3. ``twist`` and its ablations (``no_imagined``, ``no_noise``): an image RSSM trained
   with the teacher frozen on slices of ``D`` with latent distillation (Eq. 3) plus
   imagined-rollout alignment (Eq. 4); deployed as pixels -> student latent -> the
   teacher's actor. Where the task has a committed readout (cartpole-balance), all three
   see through it: a frozen CNN fitted supervised to read the positions from one
   randomised image, before a state encoder and an RSSM started as the teacher's
   (``student_readout``; docs/methods.md, section 2.7); elsewhere a CNN student.
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

Usage:
    python recipes/twist_dmc.py                    # cartpole-balance: ~45 min per seed
    python recipes/twist_dmc.py --preset tiny      # seconds, used by the tests
    python recipes/twist_dmc.py --preset paper --device cuda   # six tasks x 3 seeds, 500K steps
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import simdist  # noqa: F401  (headless GL set-up before dm_control)
import torch
from tensordict.nn import TensorDictModuleBase

from simdist.agents import (AsymmetricSACAgent, AsymmetricSACConfig, DreamerAgent,
                             DreamerConfig, TwistConfig, TwistStudent)
from simdist.agents.checkpoint import read_agent_checkpoint
from simdist.agents.dreamer import DreamerPolicy
from simdist.envs import TASKS, VisualRandomisation
from simdist.modules import (RSSM_SIZES, DreamerWorldModel, PixelEncoder, ReadoutEncoder,
                             ReadingNoise, StateReadout)
from simdist.pipelines import (EpisodeReplay, OnlineConfig, ReferencePolicy, control_env,
                               dreamer_keys, evaluate_returns, load_episodes, mean_metrics,
                               snapshot_paths, stage_seed, train_dreamer_online,
                               train_resumable)
from simdist.pipelines.experiment_log import LOGGERS, make_logger, plot_curves
from simdist.pipelines.twist_report import ORACLE, format_table, plot_results, summarise
from simdist.utils import (StageRunner, load_checkpoint, resolve_device, run_jobs,
                           write_json_atomic)
from simdist.utils.cli import (check, check_builds, check_positive, exit_on_folder_errors,
                               parse_config)
from simdist.utils.machine import describe_machine, machine_line
from simdist.utils.stages import ABSENT_MEANS
from simdist.viz.student_view import record_student_episode

TWIST = "TWIST (student)"
# stage suffix -> (table name, TwistConfig overrides): the paper's two ablations
STUDENTS = {"twist": (TWIST, {}),
            "no_imagined": ("TWIST w/o imagined alignment", {"imagined": False}),
            "no_noise": ("TWIST w/o action noise", {"action_noise_std": 0.0})}
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
    """Flat recipe config; presets below override fields. Saved as ``config.json``."""

    tasks: list[str] = field(default_factory=lambda: ["cartpole-balance"])  # control-suite tasks
    seeds: list[int] = field(default_factory=lambda: [0])  # one chain of stages per task and seed
    model_size: str = "compact"  # RSSM size of teacher, student and pixel Dreamers
    # online budget: the same environment steps for the teacher and every online baseline.
    # Measured on cartpole-balance (state teacher, 10 evaluation episodes): Oracle 680 / 612
    # at 6000 steps (seeds 0 / 1), *below* doing nothing (746); at 10000 677-939 over seven
    # teachers, four of them below doing nothing; seeds 1 / 2 went from 704 / 697 at 10000
    # to 818 / 911 at 11000 and 884 / 932 at 14000 (benchmarks/README.md, "Teacher
    # selection and a longer teacher").
    env_steps: int = 12000
    prefill_steps: int = 1000  # random-action steps before the first update
    train_every: int = 2  # teacher: one update per 2 agent steps (measured: 8 does not learn)
    # pixel Dreamers: an update costs ~4x the teacher's on CPU, so they get fewer updates
    # at the default (the paper preset gives every method the same ratio)
    pixel_train_every: int = 20  # pixel Dreamers: one update per this many agent steps
    episode_steps: int = 500  # steps per training episode
    slice_len: int = 50  # online Dreamers: steps per training slice
    slices: int = 16  # online Dreamers: slices per update
    # student (TWIST: slices of 50, imagination horizon 15, action noise 0.3)
    student_updates: int = 300  # student distillation updates on the teacher's data
    student_slice_len: int = 50  # student: steps per slice
    student_slices: int = 8  # student: slices per update
    horizon: int = 15  # imagination horizon (actor-critic and imagined alignment)
    action_noise_std: float = 0.3  # TWIST's action noise in the imagined rollouts
    imagination_starts: int = 256  # per update, for the actor-critic and Eq. 4
    # The student's pixel encoder and its input augmentation (benchmarks/README.md, TWIST
    # probe). Measured with the supervised probe (900 updates of 128 images): the evaluation's
    # camera jitter drives the plain CNN's held-out R^2 negative (cart x -3.5, cos(pole)
    # -1.7); LayerNorm + per-image input standardisation + a 4 px random shift give +0.41 /
    # +0.41. Student return at 300 updates unchanged within noise (212 +- 29 vs 215 +- 43).
    student_depth: int | None = None  # None: the model size's CNN depth (32: probe +0.05-0.15)
    student_norm: str | None = "layer"  # None or "layer" (PixelEncoder.norm)
    student_input_norm: str = "image"  # or "fixed" (PixelEncoder.input_norm)
    student_shift_pad: int = 4  # DrQ random shift in pixels, 0: none
    student_shift_per: str = "sequence"  # one draw per slice, or "frame"
    student_rotate_deg: float = 0.0  # random in-plane rotation (probe: within noise at 5)
    # "dreamer" CNN or "keypoints" (spatial softmax, PixelEncoder.arch). Probe, 600 updates:
    # held-out R^2 cart x / pole tilt .78 / .38 vs .48 / .02; student return unchanged
    # within noise at 300 updates (benchmarks/README.md, keypoint encoder), so not default.
    student_arch: str = "dreamer"
    student_lr: float = 3e-4  # 1e-3: probe better, student return not (186 +- 23 at 900)
    # The student's eyes (docs/methods.md, section 2.7). "auto": the committed readout of
    # the task (src/simdist/checkpoints/twist_readout/<task>.pt) if it has one for the
    # run's camera, else the CNN student above; "none": the CNN student; or the path of a
    # readout file (StateReadout.save). A readout student reads the positions through that
    # frozen, supervised CNN and trains on D's runs inside the readout's fitted domain,
    # each image read once. Measured on cartpole-balance, three seeds (README): 67%
    # [59, 74] of the pooled Oracle at 1800 updates; the CNN student 35% [33, 37].
    student_readout: str = "auto"
    readout_student_updates: int = 1800  # 0.17 s each on one CPU core (readings cached)
    readout_student_lr: float = 1e-3
    readout_student_slices: int = 16
    # fresh Gaussian noise on the readings in every update, in multiples of each reading's
    # spread over the readout's domain (its std); 0: none. The readout's own error is
    # ~0.07 of the spread on training scenes (its .json); 0.1 measured worse on seeds 1
    # and 2 (300 / 348 against 353 / 443; benchmarks/README.md)
    readout_student_reading_noise: float = 0.0
    # what a readout student's state encoder reads in training: "positions", the exact
    # values of the readout's dimensions that D records (privileged, like the teacher's
    # state), or "readings", the readout's readings of D's images (so it learns on the
    # readout's errors); either way it deploys through the readout, from pixels. Measured,
    # four seeds of 12000-step teachers (benchmarks/README.md, "Teacher selection and a
    # longer teacher"): 76% [71, 82] of the Oracle against 68% [61, 73]; per seed +4,
    # +243, -220, +289 points of return, so not separated over seeds.
    readout_student_inputs: str = "positions"
    # which of D's steps a readout student trains on: "domain", the runs whose states lie
    # in the readout's fitted domain (StateReadout.covers); "all", every step of D (only
    # with exact positions: outside its domain the readout's readings are extrapolations,
    # D's recorded values are not). Two entries: one candidate student on each (separate
    # stages, side by side with --jobs 2), and the one with the better validation return
    # is deployed (select_student: exact positions in the simulator, validation seeds).
    # Measured, five seeds of 12000-step teachers (benchmarks/README.md, "Which of D a
    # readout student trains on, and choosing between two"): per seed the two sets differ
    # by -349 to +281 points with equal means, and validation picks the better one.
    readout_student_states: list[str] = field(default_factory=lambda: ["all", "domain"])
    # More candidates, distilled from the teacher's *last* snapshot (one per entry, on
    # that set of D) when it is not the deployed one; the validation picks among every
    # candidate, and a chosen one deploys with the actor of the snapshot it learned from.
    # The snapshot with the best return of its own is not always the one that distils
    # best: a fresh seed's teacher chose its earliest snapshot (validation 964) and its
    # students validated at ~400, while students of its later snapshots (802-873, down to
    # 771 for the last) validated at 668-805, rising with the snapshot (benchmarks/README.md,
    # "Which snapshot to distil from"). []: candidates of the deployed teacher only.
    student_last_teacher_states: list[str] = field(default_factory=lambda: ["all"])
    student_select_episodes: int = 10  # validation episodes per candidate student
    # The teacher stage records D under training randomisation; True adds a camera-pose
    # draw every step (TRAIN_CAMERA_JITTER: 1.5x the evaluation's widths, a margin instead
    # of the test scene's exact range). Not in TWIST's training DR (camera at evaluation
    # only). Measured (benchmarks/README.md, TWIST perception, H1; one seed): probe held-out
    # R^2 (x, cos) at 900 updates .40/.28 vs .47/.31 without; student 245 +- 28 vs 240 +- 44.
    train_camera: bool = False
    # Whether the teacher stage renders D's images (12000 software renders, ~5 min on one
    # core at 64 px): "auto" renders them only when a student reads them (the CNN student,
    # or a readout student trained on "readings"); the default readout student trains on
    # the exact positions D records and sees pixels only through its frozen readout at
    # evaluation. The teacher is the same either way (rendering draws no random number
    # the physics or the teacher's training uses; tested). "always" keeps them for
    # benchmarks/twist_diagnosis.py and benchmarks/twist_dagger.py, which read them.
    teacher_pixels: str = "auto"
    # Which of the task model's cameras renders every pixel method's images (D, the pixel
    # Dreamers, SAC, evaluation); None: the task's (DreamerV2's camera 0). Cartpole's
    # camera 1 ("lookatcart") turns to the cart from 2.8 m instead of watching the rail
    # from 4 m: at 64 px the pole is ~2 px wide instead of 1, and a 0.05 rad lean changes
    # ~3x the image. The evaluation's camera jitter applies to either (benchmarks/README.md,
    # "Which camera"). Not TWIST's protocol, which keeps the task's camera.
    camera_id: int | None = None
    # The teacher's actor learns in imagination reading each latent with fresh Gaussian
    # noise of this many feature stds (DreamerConfig.actor_input_noise), so that it acts
    # sensibly on a latent that is somewhat wrong, as a pixel student's is; the Oracle is
    # evaluated without noise. 0: TWIST's teacher (benchmarks/README.md, "A teacher that
    # tolerates a student's errors").
    teacher_actor_noise: float = 0.0
    # Teacher selection: keep the teacher's weights after each of its last
    # teacher_snapshots training episodes and deploy the snapshot with the best mean return
    # over teacher_select_episodes state episodes on validation seeds of their own (neither
    # the training nor the evaluation seeds); 0: the last weights, as TWIST. A teacher's
    # return swings by 100-200 from one snapshot to the next at this budget (seed 3's
    # validated snapshots 685-901 over its last 10 episodes), and a student copies a teacher
    # that balances better than one that does not (benchmarks/README.md, "Teacher
    # selection and a longer teacher"). Costs ~1 s per snapshot on the state env.
    teacher_snapshots: int = 10
    teacher_select_episodes: int = 10
    # Asymmetric SAC baseline (pixel actor, state critic): the same environment steps and
    # training DR as the pixel Dreamers; one SAC update of sac_batch transitions per
    # sac_train_every agent steps (an update costs about a tenth of a pixel-Dreamer one)
    sac_train_every: int = 4
    sac_batch: int = 128
    # the SAC actor reads this many stacked images (AsymmetricSACConfig.frames; 1: the
    # current image alone, which holds no velocity)
    sac_frames: int = field(default=3, metadata={ABSENT_MEANS: 1})
    # the SAC critic's n-step return and its targets' Polyak rate (AsymmetricSACConfig's
    # n_step and tau). Measured on cartpole without DR, 3000 updates, three frames: 3 and
    # 0.02 balance on the training scene (976 of ~1000), 1 and 0.005 do not (339, random
    # actions 319; benchmarks/README.md, "Asymmetric SAC that balances")
    # (folders made before the three fields existed ran with 1 frame, 1 step and 0.005)
    sac_n_step: int = field(default=3, metadata={ABSENT_MEANS: 1})
    sac_tau: float = field(default=0.02, metadata={ABSENT_MEANS: 0.005})
    # DreamerV2's 8e-5 needs ~10x more updates than a CPU budget allows (measured)
    actor_lr: float = 3e-4  # actor learning rate (teacher and pixel Dreamers)
    critic_lr: float = 3e-4  # critic learning rate (teacher and pixel Dreamers)
    # the pixel Dreamers' actor (DreamerConfig.actor_distribution): the teacher's
    # "tanh_normal" or DreamerV2's "trunc_normal"
    pixel_actor_distribution: str = "tanh_normal"
    # how the pixel Dreamers explore (DreamerConfig.exploration): "noise", the actor's
    # mode plus noise (the teacher's), or "sample", draws from the actor (DreamerV2)
    pixel_exploration: str = "noise"
    # how the pixel Dreamers' actor learns (DreamerConfig.actor_gradient): "dynamics",
    # the returns backpropagated through the world model (the teacher's), or "reinforce",
    # score function with the critic as baseline (DreamerV3)
    pixel_actor_gradient: str = "dynamics"
    # the pixel Dreamers' reward weight in their world-model loss (DreamerConfig.
    # reward_scale; the teacher's is 1)
    pixel_reward_scale: float = 1.0
    # how the pixel Dreamers read their image (DreamerConfig.encoder): "dreamer", the CNN,
    # or "keypoints", spatial-softmax keypoints
    pixel_encoder: str = "dreamer"
    # Dreamer State Recon.'s state target standardised per dimension by running statistics
    # (DreamerConfig.standardise_reconstruction); raw, the pole's angular velocity carries
    # ~90% of the reconstruction loss (benchmarks/README.md, "A standardised state target
    # for Dreamer State Recon."; folders made before the field reconstructed the raw state)
    state_recon_standardise: bool = field(default=True, metadata={ABSENT_MEANS: False})
    # the state teacher's reconstruction target standardised the same way (off: every
    # teacher so far reconstructed the raw state)
    teacher_standardise: bool = False
    # the Dreamers' actor returns (teacher and pixel Dreamers; DreamerConfig.
    # return_normalisation): "none" (DreamerV2) or "percentile", divided by their running
    # 95th-5th percentile range (DreamerV3), so the entropy bonus is not swamped
    return_normalisation: str = "none"
    # evaluation on held-out scenes
    eval_episodes: int = 10  # measured: with 4, one student scored 209 and 250 on two draws
    eval_steps: int = 500  # steps per evaluation episode
    record: bool = True  # a rerun recording of one student episode
    output_dir: str = "outputs/twist_dmc"  # stages, results and plots go here
    # where the networks train and act ("cpu", "cuda", "auto"); envs, rendering and
    # replay stay on the CPU. Not part of the results: a run may resume on another device.
    device: str = "cpu"

    # False: only the teacher chain (teacher, Oracle, references, TWIST and its two
    # ablations), without the pixel-Dreamer and Asymmetric-SAC baselines, whose chains
    # cost more CPU time than the rest. Not part of the results (it picks rows, not
    # figures): a later run with True into the same folder adds the baselines.
    baselines: bool = True
    # which of TWIST and its ablations to distil (keys of STUDENTS: twist, no_imagined,
    # no_noise), e.g. ["twist"] to skip the ablations: each is a 500-900 s stage on the
    # CPU default. Not part of the results (it picks rows, not figures): a later run with
    # more students into the same folder adds them; the recording needs "twist".
    students: list[str] = field(default_factory=lambda: list(STUDENTS))
    # stages run side by side in this many processes (teacher chain beside the pixel
    # Dreamers). Not part of the results.
    jobs: int = min(2, os.cpu_count() or 1)  # 2 on two or more cores
    # scalar logs of every training update under <output_dir>/logs: csv, tensorboard
    # (needs tensorboard), wandb (offline; needs wandb) or none. Not part of the results.
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


def saved_meta(cfg: Config, task: str, seed: int) -> dict:
    """What a saved agent file records besides its weights: the task, the seed and the
    camera its pixels came from, which ``recipes/evaluate.py`` reads (the evaluation
    scenes and seeds are its own flags)."""
    return {"task": task, "seed": seed, "camera_id": cfg.camera_id}


def teacher_agent(cfg: Config, task: str) -> DreamerAgent:
    config = dataclasses.replace(cfg.dreamer(), actor_input_noise=cfg.teacher_actor_noise,
                                 standardise_reconstruction=cfg.teacher_standardise)
    return DreamerAgent.for_state(*state_dim(task), config).to(cfg.device)


def records_images(cfg: Config, task: str) -> bool:
    """Whether the teacher stage renders D's images: only a student that reads them
    needs them (the CNN student, or a readout student trained on the readout's readings),
    unless ``cfg.teacher_pixels`` is ``"always"``."""
    return (cfg.teacher_pixels == "always" or readout_file(cfg, task) is None
            or cfg.readout_student_inputs == "readings")


def teacher_stage(cfg: Config, task: str, seed: int, stage_dir: Path) -> dict:
    """State Dreamer whose collected experience is D, with the domain-randomised image
    of every step when a student reads them (:func:`records_images`)."""
    torch.manual_seed(seed)
    agent = teacher_agent(cfg, task)
    images = records_images(cfg, task)
    env = control_env(task, seed, pixels=images, visual=training_visual(cfg) if images else None,
                      max_episode_steps=cfg.episode_steps, primer=agent.make_primer(),
                      camera_id=cfg.camera_id)
    keys = dreamer_keys("state", "pixels") if images else dreamer_keys("state")
    out = train_dreamer_online(agent, env, cfg.online(), stage_dir,
                               keys, desc=f"teacher {task} s{seed}",
                               seed=stage_seed(seed, f"{task}/teacher"),
                               logger=make_logger(cfg.logger, cfg.output_dir),
                               snapshots=cfg.teacher_snapshots)
    env.close()
    selection = None
    if cfg.teacher_snapshots:
        selection = select_teacher(cfg, task, seed,
                                   snapshot_paths(stage_dir)[-cfg.teacher_snapshots:])
        agent.load_weights(load_checkpoint(selection["chosen"])["weights"], selection["chosen"])
    # the deployed teacher (the chosen snapshot, or the last weights), self-describing: what
    # the Oracle, the students and recipes/evaluate.py load (agent.pt is the training
    # checkpoint, which goes on from the last weights)
    agent.save(stage_dir / "teacher_agent.pt", optimisers=False, meta=saved_meta(cfg, task, seed))
    return {"checkpoint": str(stage_dir / "agent.pt"), "data": str(stage_dir),
            "agent": str(stage_dir / "teacher_agent.pt"), "selection": selection,
            "images": images,
            "episode_returns": out["episode_returns"], "updates": out["updates"],
            "last": mean_metrics(out["history"])}


def select_teacher(cfg: Config, task: str, seed: int, snapshots: list[Path]) -> dict:
    """The snapshot (weights the teacher stage kept) whose deterministic policy has the
    best mean return over ``cfg.teacher_select_episodes`` state episodes on validation
    seeds drawn for this purpose (not the evaluation's ``seed + 10000``); ties go to the
    later one.

    Returns:
        ``{"chosen": path, "candidates": [{"snapshot": path, "mean": ..., "std": ...}]}``.
    """
    if not snapshots:
        raise RuntimeError("teacher selection: the teacher stage kept no snapshot")
    validation_seed = stage_seed(seed, f"{task}/teacher_selection")
    candidates, agent = [], teacher_agent(cfg, task)
    for path in snapshots:
        agent.load_weights(load_checkpoint(path)["weights"], path)
        stats = evaluate_returns(task, agent.policy(explore=False), agent.make_primer(),
                                 validation_seed, cfg.teacher_select_episodes, cfg.eval_steps,
                                 pixels=False, visual=None)
        candidates.append({"snapshot": str(path), "mean": stats["mean"], "std": stats["std"]})
        print(f"teacher selection {task} s{seed}: {path.name} {stats['mean']:.1f}", flush=True)
    best = max(range(len(candidates)), key=lambda i: (candidates[i]["mean"], i))
    return {"chosen": candidates[best]["snapshot"], "candidates": candidates}


def load_teacher(cfg: Config, task: str, teacher: dict) -> DreamerAgent:
    """The deployed teacher of a finished teacher stage (its ``teacher_agent.pt``)."""
    agent = teacher_agent(cfg, task)
    agent.load_weights(read_agent_checkpoint(teacher["agent"])["weights"], teacher["agent"])
    return agent


def evaluate(cfg: Config, task: str, seed: int, policy, primer, pixels: bool,
             own_scene: bool = False) -> dict:
    """Held-out scenes (textures never seen in training), the same seeds for all methods;
    ``own_scene``: dm_control's own scene instead (where a no-DR baseline trained)."""
    visual = VisualRandomisation.heldout_evaluation() if pixels and not own_scene else None
    return evaluate_returns(task, policy, primer, seed + 10_000, cfg.eval_episodes,
                            cfg.eval_steps, pixels, visual, camera_id=cfg.camera_id)


def twist_config(cfg: Config, overrides: dict) -> TwistConfig:
    """The recipe's student settings, with an ablation's ``overrides`` on top."""
    config = TwistConfig(horizon=cfg.horizon, action_noise_std=cfg.action_noise_std,
                         max_imagination_starts=cfg.imagination_starts,
                         shift_pad=cfg.student_shift_pad, shift_per=cfg.student_shift_per,
                         rotate_deg=cfg.student_rotate_deg, lr=cfg.student_lr)
    return dataclasses.replace(config, **overrides)


def new_student(cfg: Config, task: str, teacher: DreamerAgent, overrides: dict) -> TwistStudent:
    student = DreamerWorldModel.student(teacher.actor.action_dim, cfg.model_size,
                                        depth=cfg.student_depth, norm=cfg.student_norm,
                                        input_norm=cfg.student_input_norm,
                                        arch=cfg.student_arch)
    return TwistStudent(teacher, student, twist_config(cfg, overrides)).to(cfg.device)


#: the committed readouts, one per task (``<task>.pt`` and ``<task>.json``)
READOUT_DIR = Path(__file__).resolve().parents[1] / "checkpoints" / "twist_readout"


def _readout_file_ok(path: str) -> bool:
    return Path(path).is_file() and Path(path).with_suffix(".json").is_file()


def readout_file(cfg: Config, task: str) -> Path | None:
    """The readout file a student of ``task`` sees through (``Config.student_readout``),
    or ``None`` for the CNN student. Refuses a readout fitted for another task or camera."""
    if cfg.student_readout == "none":
        return None
    path = READOUT_DIR / f"{task}.pt" if cfg.student_readout == "auto" else Path(
        cfg.student_readout)
    if cfg.student_readout == "auto" and not path.exists():
        return None  # no committed readout for this task: the CNN student
    meta = json.loads(path.with_suffix(".json").read_text())
    fits = meta.get("task", task) == task and meta.get("camera_id") == cfg.camera_id
    if cfg.student_readout == "auto" and not fits:
        return None
    if not fits:
        raise ValueError(f"student_readout {path} was fitted for task {meta.get('task')!r}, "
                         f"camera {meta.get('camera_id')}; this run is {task!r}, camera "
                         f"{cfg.camera_id}")
    return path


def new_readout_student(cfg: Config, task: str, teacher: DreamerAgent, readout: StateReadout,
                        overrides: dict) -> TwistStudent:
    """A student that sees through the frozen ``readout``, its RSSM starting as the
    teacher's (docs/methods.md, section 2.7); trained by TWIST's losses like the CNN student."""
    model = DreamerWorldModel.readout_student(readout, teacher.actor.action_dim, cfg.model_size)
    # readings are not images: no shift or rotation
    config = twist_config(cfg, {"shift_pad": 0, "rotate_deg": 0.0,
                                "lr": cfg.readout_student_lr, **overrides})
    noise = cfg.readout_student_reading_noise
    twist = TwistStudent(teacher, model, config,
                         augment=ReadingNoise(noise * readout.std) if noise else None)
    twist.start_from_teacher_rssm()
    return twist.to(cfg.device)


def build_student(cfg: Config, task: str, teacher: DreamerAgent, overrides: dict) -> TwistStudent:
    """The run's student of ``task``: a readout student if it has a readout, else the CNN."""
    path = readout_file(cfg, task)
    if path is None:
        return new_student(cfg, task, teacher, overrides)
    return new_readout_student(cfg, task, teacher, StateReadout.load(path), overrides)


def mask_runs(keep: torch.Tensor, min_len: int) -> list[tuple[int, int]]:
    """``(start, end)`` of each run of consecutive ``True`` in the mask ``keep`` ``[T]``
    that is at least ``min_len`` steps long.

    Examples:
        >>> mask_runs(torch.tensor([1, 1, 0, 1, 1, 1, 0], dtype=torch.bool), 2)
        [(0, 2), (3, 6)]
    """
    edges = torch.diff(torch.cat([torch.tensor([0]), keep.int().cpu(), torch.tensor([0])]))
    starts = (edges == 1).nonzero().flatten().tolist()
    ends = (edges == -1).nonzero().flatten().tolist()
    return [(a, b) for a, b in zip(starts, ends) if b - a >= min_len]


def with_readings(episode, readout: StateReadout):
    """A shallow copy of ``episode`` whose ("next", "pixels") are ``readout``'s readings of
    them (the images are read once: the readout is frozen, so a student trains on the same
    batches as if it read them at every update)."""
    return _with_pixels(episode, readout.read(recorded_images(episode)))


def recorded_images(episode) -> torch.Tensor:
    """The images a teacher stage recorded with an episode of D: a clear error when it
    recorded none (:func:`records_images`)."""
    if ("next", "pixels") not in episode.keys(True):
        raise ValueError("this D holds no images: the teacher stage renders them only when "
                         "a student reads them (Config.teacher_pixels); rerun the recipe "
                         "with --teacher-pixels always into a new output folder")
    return episode["next", "pixels"]


def with_positions(episode, readout: StateReadout):
    """A shallow copy of ``episode`` whose ("next", "pixels") are the exact values of the
    readout's dimensions, from the recorded state (what a perfect readout would read)."""
    return _with_pixels(episode, readout_positions(episode["next", "state"], readout))


def readout_positions(state: torch.Tensor, readout: StateReadout) -> torch.Tensor:
    """The exact values ``[..., len(dims)]`` of the readout's dimensions of ``state``."""
    return state.index_select(-1, readout.dims.to(state.device)).float()


def _with_pixels(episode, pixels: torch.Tensor):
    """A shallow copy of ``episode`` with ("next", "pixels") replaced (the caller's
    episode is left as it was)."""
    out = episode.clone(recurse=False)
    out["next"] = episode["next"].clone(recurse=False)
    out["next", "pixels"] = pixels
    return out


def readout_training_runs(episodes: list, readout: StateReadout, min_len: int,
                          exact: bool = False, everywhere: bool = False) -> list:
    """What a readout student trains on: each run of consecutive steps of ``episodes``
    whose states lie in the readout's fitted domain and that is at least ``min_len`` steps
    long, as an episode of the readout's readings (:func:`with_readings`), or with
    ``exact`` of the exact values it reads (:func:`with_positions`). Outside its domain a
    readout extrapolates, so the student would learn the teacher's latent from readings
    it cannot trust. ``everywhere`` (with ``exact`` only): every episode whole, domain or
    not (the recorded values are exact everywhere)."""
    if everywhere and not exact:
        raise ValueError("everywhere=True needs exact=True: outside its fitted domain the "
                         "readout's readings are extrapolations")
    convert = with_positions if exact else with_readings
    if everywhere:
        return [convert(episode, readout) for episode in episodes if len(episode) >= min_len]
    return [convert(episode[start:end], readout) for episode in episodes
            for start, end in mask_runs(readout.covers(episode["next", "state"]), min_len)]


def train_student(cfg: Config, task: str, seed: int, teacher: dict, overrides: dict,
                  stage_dir: Path, states: str | None = None) -> tuple[TwistStudent, dict]:
    """Distils a student from the frozen teacher on ``D`` (resumable from
    ``stage_dir/student.pt``); a readout student trains on the ``states`` of D ("all" or
    "domain"; default: the config's first). Returns the student and what it trained on."""
    torch.manual_seed(seed)
    agent = load_teacher(cfg, task, teacher)
    twist = build_student(cfg, task, agent, overrides)
    episodes = [e.to_tensordict() for e in load_episodes(teacher["data"])]
    readout, updates, slices = None, cfg.student_updates, cfg.student_slices
    states = states or cfg.readout_student_states[0]
    if isinstance(twist.student.encoder, ReadoutEncoder):
        readout, updates = twist.student.encoder.readout, cfg.readout_student_updates
        slices = cfg.readout_student_slices
        episodes = readout_training_runs(episodes, readout, cfg.student_slice_len,
                                         exact=cfg.readout_student_inputs == "positions",
                                         everywhere=states == "all")
        if not episodes:
            raise RuntimeError(f"the teacher's data holds no run of {cfg.student_slice_len} "
                               f"steps inside the readout's domain {readout.domain}: "
                               f"nothing for a readout student to train on")
    replay = EpisodeReplay(cfg.env_steps + cfg.episode_steps, cfg.student_slice_len, slices)
    for episode in episodes:
        replay.add(episode)
    history = train_resumable(twist.update, replay.sample, updates,
                              {"twist": twist}, stage_dir / "student.pt",
                              every=max(1, updates // 10),
                              desc=f"{stage_dir.name}", seed=stage_seed(seed, stage_dir.name),
                              logger=make_logger(cfg.logger, cfg.output_dir))
    return twist, {"checkpoint": str(stage_dir / "student.pt"), "updates": updates,
                   "student": "readout" if readout is not None else "cnn",
                   "readout": str(readout_file(cfg, task)) if readout is not None else None,
                   "states": states if readout is not None else None,
                   "train_steps": len(replay),
                   "first": mean_metrics(history[:10], 10), "last": mean_metrics(history, 50)}


def deploy_student(cfg: Config, task: str, seed: int, twist: TwistStudent, trained: dict,
                   stage_dir: Path) -> dict:
    """Saves the student as a deployable agent and evaluates it from pixels."""
    # deployable alone (carries the teacher's actor): recipes/evaluate.py --checkpoint
    twist.save(stage_dir / "student_agent.pt", optimisers=False, meta=saved_meta(cfg, task, seed))
    result = evaluate(cfg, task, seed, twist.policy(), twist.make_primer(), pixels=True)
    return {**result, **trained, "agent": str(stage_dir / "student_agent.pt")}


def student_stage(cfg: Config, task: str, seed: int, teacher: dict, overrides: dict,
                  stage_dir: Path) -> dict:
    """Distils a student from the frozen teacher on ``D``, then evaluates it from pixels."""
    twist, trained = train_student(cfg, task, seed, teacher, overrides, stage_dir)
    return deploy_student(cfg, task, seed, twist, trained, stage_dir)


class ExactPositions(TensorDictModuleBase):
    """A readout student's policy fed the exact values of its readout's dimensions from
    the simulator's ``"state"`` (perfect perception): validates what distillation taught
    the student without rendering.

    Examples:
        >>> from tensordict import TensorDict
        >>> from simdist.modules import PixelEncoder
        >>> teacher = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
        >>> readout = StateReadout(PixelEncoder(4), state_dim=5, dims=[0, 1, 2])
        >>> twist = TwistStudent(teacher, DreamerWorldModel.readout_student(readout, 1, "tiny"))
        >>> policy = ExactPositions(twist)
        >>> td = policy(TensorDict({"state": torch.zeros(2, 5),
        ...                         "is_init": torch.ones(2, 1, dtype=torch.bool)}, [2]))
        >>> td["action"].shape
        torch.Size([2, 1])
    """

    def __init__(self, twist: TwistStudent):
        super().__init__()
        self.readout = twist.student.encoder.readout
        self.policy = DreamerPolicy(twist.student, twist.teacher.actor, "positions",
                                    explore=False)
        self.in_keys = ["state", *[k for k in self.policy.in_keys if k != "positions"]]
        self.out_keys = list(self.policy.out_keys)

    def forward(self, td):
        td.set("positions", readout_positions(td["state"], self.readout))
        return self.policy(td).exclude("positions")


def validate_student(cfg: Config, task: str, seed: int, twist: TwistStudent) -> dict:
    """Mean return of a readout student fed exact positions (:class:`ExactPositions`) on
    ``cfg.student_select_episodes`` state episodes of validation seeds drawn for this
    purpose (neither training nor the evaluation's ``seed + 10000``)."""
    stats = evaluate_returns(task, ExactPositions(twist),
                             twist.make_primer(), stage_seed(seed, f"{task}/student_selection"),
                             cfg.student_select_episodes, cfg.eval_steps, pixels=False,
                             visual=None)
    return {"mean": stats["mean"], "std": stats["std"], "returns": stats["returns"]}


def last_snapshot(teacher: dict) -> str | None:
    """The path of the last snapshot a finished teacher stage validated, or None when
    there is none or it is the deployed teacher itself."""
    selection = teacher.get("selection")
    if not selection or not selection["candidates"]:
        return None
    last = selection["candidates"][-1]["snapshot"]
    return None if last == selection["chosen"] else last


def snapshot_teacher(cfg: Config, task: str, seed: int, teacher: dict, snapshot: str,
                     stage_dir: Path) -> dict:
    """``teacher`` (a teacher stage's result) with the weights of ``snapshot`` as its
    deployed agent, saved as ``stage_dir/teacher_agent.pt`` (D is the same)."""
    agent = teacher_agent(cfg, task)
    agent.load_weights(load_checkpoint(snapshot)["weights"], snapshot)
    stage_dir.mkdir(parents=True, exist_ok=True)
    agent.save(stage_dir / "teacher_agent.pt", optimisers=False, meta=saved_meta(cfg, task, seed))
    return {**teacher, "agent": str(stage_dir / "teacher_agent.pt")}


def candidate_student_stage(cfg: Config, task: str, seed: int, teacher: dict,
                            overrides: dict, states: str, stage_dir: Path,
                            snapshot: str = "best") -> dict:
    """One candidate readout student, trained on ``states`` of D and validated, distilled
    from the deployed teacher (``snapshot="best"``) or from the teacher stage's last
    snapshot (``"last"``; skipped, with ``validation`` None, when that is the deployed one)."""
    if snapshot == "last":
        last = last_snapshot(teacher)
        if last is None:
            print(f"candidate {stage_dir.name}: the last snapshot is the deployed teacher, "
                  f"skipped", flush=True)
            return {"skipped": "the teacher's last snapshot is its deployed one",
                    "validation": None}
        teacher = snapshot_teacher(cfg, task, seed, teacher, last, stage_dir)
    twist, trained = train_student(cfg, task, seed, teacher, overrides, stage_dir, states)
    validation = validate_student(cfg, task, seed, twist)
    print(f"candidate {stage_dir.name}: validation {validation['mean']:.1f}", flush=True)
    return {**trained, "validation": validation, "teacher_agent": teacher["agent"]}


def select_student(candidates: dict[str, dict]) -> str:
    """The candidate (name -> its stage result) with the best validation mean; ties go to
    the earlier one in ``candidates``' order; skipped candidates (validation None) never."""
    names = [n for n in candidates if candidates[n]["validation"] is not None]
    if not names:
        raise RuntimeError(f"no trained candidate student among {list(candidates)}")
    return max(names, key=lambda n: (candidates[n]["validation"]["mean"], -names.index(n)))


def selected_student_stage(cfg: Config, task: str, seed: int, teacher: dict, overrides: dict,
                           candidates: dict[str, dict], stage_dir: Path) -> dict:
    """Deploys the candidate student with the best validation return (its weights copied
    into this stage as ``student.pt``) and evaluates it from pixels."""
    chosen = select_student(candidates)
    # a candidate of another snapshot deploys with that snapshot's actor
    teacher = {**teacher, "agent": candidates[chosen].get("teacher_agent", teacher["agent"])}
    torch.manual_seed(seed)
    twist = build_student(cfg, task, load_teacher(cfg, task, teacher), overrides)
    state = load_checkpoint(candidates[chosen]["checkpoint"])
    twist.load_state_dict(state["state"]["twist"])
    stage_dir.mkdir(parents=True, exist_ok=True)  # the recording reads the stage's student.pt
    shutil.copyfile(candidates[chosen]["checkpoint"], stage_dir / "student.pt.tmp")
    os.replace(stage_dir / "student.pt.tmp", stage_dir / "student.pt")
    trained = {**candidates[chosen], "checkpoint": str(stage_dir / "student.pt"),
               "teacher_agent": teacher["agent"], "chosen": chosen,
               "candidates": {n: {"checkpoint": c.get("checkpoint"),
                                  "validation": c["validation"]}
                              for n, c in candidates.items()}}
    trained.pop("validation")
    return deploy_student(cfg, task, seed, twist, trained, stage_dir)


def pixel_dreamer_stage(cfg: Config, task: str, seed: int, visual, stage_dir: Path,
                        state_recon: bool = False) -> dict:
    """A pixel-Dreamer baseline; ``state_recon``: its decoder reconstructs the state."""
    torch.manual_seed(seed)
    n_state, n_action = state_dim(task)
    agent = (DreamerAgent.for_pixels_state_recon(n_action, n_state, cfg.pixel_dreamer())
             if state_recon else DreamerAgent.for_pixels(n_action, cfg.pixel_dreamer())
             ).to(cfg.device)
    env = control_env(task, seed, pixels=True, visual=visual,
                      max_episode_steps=cfg.episode_steps, primer=agent.make_primer(),
                      camera_id=cfg.camera_id)
    keys = dreamer_keys("pixels", "state") if state_recon else dreamer_keys("pixels")
    out = train_dreamer_online(agent, env, cfg.online(pixels=True), stage_dir,
                               keys, desc=stage_dir.name,
                               seed=stage_seed(seed, stage_dir.name),
                               logger=make_logger(cfg.logger, cfg.output_dir))
    env.close()
    agent.save(stage_dir / "dreamer_agent.pt", optimisers=False, meta=saved_meta(cfg, task, seed))
    policy = agent.policy(explore=False)
    result = evaluate(cfg, task, seed, policy, agent.make_primer(), pixels=True)
    if visual is None:  # also where it trained (dm_control's scene): did it learn at all?
        result["own_scene"] = evaluate(cfg, task, seed, policy, agent.make_primer(),
                                       pixels=True, own_scene=True)
    return {**result, "agent": str(stage_dir / "dreamer_agent.pt"),
            "episode_returns": out["episode_returns"], "updates": out["updates"],
            "last": mean_metrics(out["history"])}


def asymmetric_sac_stage(cfg: Config, task: str, seed: int, stage_dir: Path,
                         visual=VisualRandomisation.training()) -> dict:
    """TWIST's model-free baseline: SAC whose actor sees DR pixels (``visual``; ``None``:
    dm_control's own scene) and whose critic sees the privileged state, trained online for
    the pixel Dreamers' environment steps."""
    torch.manual_seed(seed)
    agent = AsymmetricSACAgent(*state_dim(task), AsymmetricSACConfig(
        depth=RSSM_SIZES[cfg.model_size]["depth"], lr=cfg.critic_lr, frames=cfg.sac_frames,
        n_step=cfg.sac_n_step, tau=cfg.sac_tau)).to(cfg.device)
    env = control_env(task, seed, pixels=True, visual=visual,
                      max_episode_steps=cfg.episode_steps, camera_id=cfg.camera_id,
                      primer=agent.make_primer())
    out = train_dreamer_online(agent, env, cfg.sac_online(), stage_dir,
                               dreamer_keys("pixels", "state"), desc=stage_dir.name,
                               seed=stage_seed(seed, stage_dir.name),
                               logger=make_logger(cfg.logger, cfg.output_dir))
    env.close()
    agent.save(stage_dir / "sac_agent.pt", optimisers=False, meta=saved_meta(cfg, task, seed))
    policy = agent.policy(explore=False)
    result = evaluate(cfg, task, seed, policy, agent.make_primer(), pixels=True)
    if visual is None:  # also where it trained (dm_control's scene): did it learn at all?
        result["own_scene"] = evaluate(cfg, task, seed, policy, agent.make_primer(),
                                       pixels=True, own_scene=True)
    return {**result, "agent": str(stage_dir / "sac_agent.pt"),
            "checkpoint": str(stage_dir / "agent.pt"),
            "episode_returns": out["episode_returns"], "updates": out["updates"],
            "last": mean_metrics(out["history"])}


def references_stage(cfg: Config, task: str, seed: int) -> dict:
    """Zero and uniform random actions on the Oracle's evaluation seeds (state env: a
    blind policy's return does not depend on the pixels)."""
    action_dim = state_dim(task)[1]
    return {kind: evaluate(cfg, task, seed, ReferencePolicy(kind, action_dim), None,
                           pixels=False) for kind in REFERENCES}


def recording_stage(cfg: Config, task: str, seed: int, teacher: dict, out: Path) -> dict:
    agent = load_teacher(cfg, task, teacher)
    twist = build_student(cfg, task, agent, {})
    twist.load_state_dict(load_checkpoint(out / "stages" / f"{task}_s{seed}_twist" /
                                          "student.pt")["state"]["twist"])
    env = control_env(task, seed + 10_000, pixels=True,
                      visual=VisualRandomisation.heldout_evaluation(),
                      max_episode_steps=cfg.eval_steps, primer=twist.make_primer(),
                      camera_id=cfg.camera_id)
    path = record_student_episode(env, agent, twist, str(out / "rerun_student.rrd"),
                                  cfg.eval_steps)
    env.close()
    return {"path": path}


# -- the recipe -------------------------------------------------------------------------
#: settings only the Asymmetric SAC baseline's stage reads
SAC_FIELDS = ("sac_train_every", "sac_batch", "sac_frames", "sac_n_step", "sac_tau")
#: settings only the baselines' stages read (the SAC's and Dreamer State Recon.'s)
BASELINE_FIELDS = (*SAC_FIELDS, "state_recon_standardise")


def stage_runner(cfg: Config) -> StageRunner:
    # tasks, seeds, students and baselines pick which chains run (rows of the table), not
    # what a chain computes: a later run with more of them into the same folder adds them.
    # Without baselines no stage reads the baselines' own settings, so they do not bar a
    # folder.
    ignored = () if cfg.baselines else BASELINE_FIELDS
    return StageRunner(cfg.output_dir, cfg, runtime_keys=(
        "device", "jobs", "logger", "baselines", "students", "tasks", "seeds", *ignored))


def _stage(runner: StageRunner, name: str, fn) -> dict:
    if runner.done(name):
        print(f"stage {name}: already done, reusing its results", flush=True)
    return runner.run(name, fn)


def teacher_chain(cfg: Config, task: str, seed: int) -> None:
    """teacher -> Oracle, and the blind references beside them."""
    runner, key = stage_runner(cfg), f"{task}_s{seed}"
    teacher = _stage(runner, f"{key}_teacher", lambda d: teacher_stage(cfg, task, seed, d))

    def oracle(d):
        agent = load_teacher(cfg, task, teacher)
        return evaluate(cfg, task, seed, agent.policy(explore=False), agent.make_primer(),
                        pixels=False)

    _stage(runner, f"{key}_oracle", oracle)
    _stage(runner, f"{key}_references", lambda d: references_stage(cfg, task, seed))


def student_candidates(cfg: Config, task: str) -> list[str]:
    """The candidate students of ``task``, by name: each of ``readout_student_states``
    (distilled from the deployed teacher), then ``last_<states>`` for each of
    ``student_last_teacher_states`` (from the teacher's last snapshot); none unless a
    readout student has at least two."""
    names = [*cfg.readout_student_states,
             *(f"last_{states}" for states in cfg.student_last_teacher_states)]
    if readout_file(cfg, task) is None or len(names) < 2:
        return []
    return names


def candidate_chain(cfg: Config, task: str, seed: int, suffix: str, name: str) -> None:
    """One candidate of a student of :data:`STUDENTS` (``name``: see
    :func:`student_candidates`)."""
    runner, key = stage_runner(cfg), f"{task}_s{seed}"
    teacher = runner.result(f"{key}_teacher")
    snapshot, states = ("last", name[len("last_"):]) if name.startswith("last_") else ("best", name)
    _stage(runner, f"{key}_{suffix}_{name}", lambda d: candidate_student_stage(
        cfg, task, seed, teacher, STUDENTS[suffix][1], states, d, snapshot))


def student_chain(cfg: Config, task: str, seed: int, suffix: str) -> None:
    """One student of :data:`STUDENTS` (TWIST or an ablation) distilled from the finished
    teacher of ``task`` and ``seed``: the students of one teacher are independent of each
    other, so they run side by side. With candidates (:func:`student_candidates`) it
    deploys the best of their finished stages."""
    runner, key = stage_runner(cfg), f"{task}_s{seed}"
    teacher, overrides = runner.result(f"{key}_teacher"), STUDENTS[suffix][1]
    names = student_candidates(cfg, task)
    if names:
        candidates = {n: runner.result(f"{key}_{suffix}_{n}") for n in names}
        _stage(runner, f"{key}_{suffix}", lambda d: selected_student_stage(
            cfg, task, seed, teacher, overrides, candidates, d))
        return
    _stage(runner, f"{key}_{suffix}",
           lambda d: student_stage(cfg, task, seed, teacher, overrides, d))


def pixel_chain(cfg: Config, task: str, seed: int, suffix: str) -> None:
    """One pixel-Dreamer baseline: independent of the teacher, so it can run beside it."""
    runner = stage_runner(cfg)
    visual = PIXEL_DREAMERS[suffix][1]
    _stage(runner, f"{task}_s{seed}_{suffix}",
           lambda d: pixel_dreamer_stage(cfg, task, seed, visual, d,
                                         state_recon=suffix == "dreamer_state_recon"))


def sac_chain(cfg: Config, task: str, seed: int) -> None:
    """The Asymmetric SAC baseline: independent of the teacher, like the pixel Dreamers."""
    _stage(stage_runner(cfg), f"{task}_s{seed}_{ASYMMETRIC_SAC[0]}",
           lambda d: asymmetric_sac_stage(cfg, task, seed, d))


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
    stages = {suffix: STUDENTS[suffix][0] for suffix in cfg.students}  # stage -> table row
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
    write_json_atomic(out / "results.json",  # a crash mid-write keeps the previous file
        {"config": dataclasses.asdict(cfg), "results": results, "summary": summarise(results),
         "runs": records, "recording": recording, "timings_s": runner.timings,
         "wall_s": wall, "jobs": cfg.jobs, "machine": machine})
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
