"""The readout student's parts: a committed, frozen CNN that reads privileged positions from
one image, and the episodes it reads. This variant uses privileged supervision; it is not
the paper's TWIST.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
from tensordict.nn import TensorDictModuleBase

import simdist  # noqa: F401  (headless GL set-up before dm_control)
from simdist.agents import DreamerAgent, TwistStudent
from simdist.agents.dreamer import DreamerPolicy
from simdist.modules import DreamerWorldModel, ReadingNoise, StateReadout
from simdist.pipelines.twist.config import (READOUT_DIR, READOUT_STUDENTS, STUDENTS, Config,
                                           twist_config)


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


def student_row(cfg: Config, task: str, suffix: str) -> str:
    """The table name of student stage ``suffix`` of ``task``: TWIST's (or its ablation's)
    for the CNN student, the readout student's where it sees through a readout.

    Examples:
        >>> student_row(Config(), "cartpole-balance", "twist")
        'TWIST (student)'
        >>> student_row(Config(student_readout="auto"), "cartpole-balance", "twist")
        'Readout student (privileged state regression)'
    """
    if readout_file(cfg, task) is None:
        return STUDENTS[suffix][0]
    return READOUT_STUDENTS[suffix]


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


class ExactPositions(TensorDictModuleBase):
    """A readout student's policy fed the exact values of its readout's dimensions from
    the simulator's ``"state"`` (perfect perception): validates what distillation taught
    the student without rendering.

    Examples:
        >>> from tensordict import TensorDict
        >>> from simdist.agents import DreamerConfig
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
