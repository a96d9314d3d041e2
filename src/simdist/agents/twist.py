"""TWIST student: distilled from a frozen state teacher, deployed with the teacher's actor.

``TwistStudent.update`` applies Eq. 3 (latent distillation) and Eq. 4 (imagined-rollout
alignment) to the student only; ``policy()`` filters *pixels* with the student's RSSM
and acts with the teacher's actor on the student's latent (TWIST Sec. IV deployment).
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from pathlib import Path

import torch
from tensordict import TensorDictBase

from simdist.agents import checkpoint as ckpt_format
from simdist.agents.describe import build_dreamer_model, describe_dreamer_model
from simdist.agents.dreamer import DreamerAgent, DreamerPolicy, check_unit_box
from simdist.modules import DreamerWorldModel, RandomRotate, RandomShift
from simdist.objectives import ImaginedAlignmentLoss, TwistDistillationLoss
from simdist.utils.device import module_device, move_to_device


@dataclass
class TwistConfig:
    """Student training settings (TWIST: slices of 50, imagination horizon 15).

    ``shift_pad > 0`` applies DrQ's random shift (:class:`~simdist.modules.RandomShift`)
    and ``rotate_deg > 0`` a random in-plane rotation
    (:class:`~simdist.modules.RandomRotate`) to the student's images in every update
    (never at deployment): one draw per slice (``shift_per="sequence"``) or per image
    (``"frame"``). ``state_weight > 0`` adds a term that is **not** in TWIST: the
    teacher's frozen state decoder applied to the student's posterior features should
    give the privileged state, ``state_weight * ||dec_T(h^S, z^S) - s||^2`` (summed over
    state dimensions), a direct signal for the student's encoder. ``action_weight > 0``
    adds another term that is not in TWIST: the teacher's frozen actor should act on the
    student's posterior features as it acts on the teacher's, ``action_weight *
    ||pi_T(h^S, z^S) - pi_T(h^T, z^T)||^2`` (deterministic actions, summed over action
    dimensions): the latent error weighed by what it does to the deployed policy.
    ``standardise_belief``
    (not in TWIST) weighs each dimension of the belief distances of Eq. 3 and Eq. 4 by the
    inverse of the teacher's batch variance of that dimension
    (:func:`~simdist.objectives.distillation.belief_distance`).

    Examples:
        >>> from simdist.agents import DreamerConfig
        >>> teacher = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
        >>> student = DreamerWorldModel.student(action_dim=1, size="tiny")
        >>> TwistStudent(teacher, student, TwistConfig(imagined=False)).imagined is None
        True
        >>> TwistStudent(teacher, student, TwistConfig(horizon=5)).imagined.horizon
        5
    """

    lr: float = 3e-4
    grad_clip: float = 100.0
    imagined: bool = True
    horizon: int = 15
    action_noise_std: float = 0.3
    max_imagination_starts: int | None = 256
    shift_pad: int = 0
    shift_per: str = "sequence"
    rotate_deg: float = 0.0
    state_weight: float = 0.0
    action_weight: float = 0.0
    standardise_belief: bool = False

    def __post_init__(self):
        for name in ("state_weight", "action_weight", "action_noise_std"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"TwistConfig.{name} must be finite and >= 0, got {value}")


def action_error(actions: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``||actions - target||^2`` summed over action dimensions, averaged over the rest.

    Examples:
        >>> action_error(torch.tensor([[0.5, 0.0], [0.0, 0.0]]), torch.zeros(2, 2)).item()
        0.125
    """
    return (actions - target).pow(2).sum(-1).mean()


class TwistStudent(ckpt_format.LoadableAgent):
    """A pixel student distilled from a trained :class:`DreamerAgent` (the teacher).

    Args:
        teacher: the trained state agent; its world model and actor stay frozen.
        student: a ``DreamerWorldModel`` with the same RSSM sizes (e.g.
            ``DreamerWorldModel.student(action_dim, size)``).
        config: :class:`TwistConfig`; ``imagined=False`` and ``action_noise_std=0`` give
            the paper's two ablations.
        pixels_key: where the randomised images are in a batch.
        augment: a module applied to the student's observations in every update (after
            the config's shift and rotation), never at deployment, e.g.
            :class:`~simdist.modules.ReadingNoise` for a readout student's readings.

    Examples:
        >>> from tensordict import TensorDict
        >>> from simdist.agents import DreamerConfig
        >>> teacher = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
        >>> student = DreamerWorldModel.student(action_dim=1, size="tiny")
        >>> twist = TwistStudent(teacher, student, TwistConfig(horizon=3))
        >>> batch = TensorDict({"action": torch.zeros(2, 4, 1),
        ...     "is_init": torch.zeros(2, 4, 1, dtype=torch.bool),
        ...     "next": {"state": torch.zeros(2, 4, 5),
        ...              "pixels": torch.zeros(2, 4, 64, 64, 3, dtype=torch.uint8)}}, [2, 4])
        >>> sorted(k for k in twist.update(batch) if k.startswith("loss"))
        ['loss_distillation', 'loss_imagined']
    """

    def __init__(self, teacher: DreamerAgent, student: DreamerWorldModel,
                 config: TwistConfig = TwistConfig(), pixels_key=("next", "pixels"),
                 augment: torch.nn.Module | None = None):
        self.teacher, self.student, self.config = teacher, student, config
        teacher_obs = ("next", teacher.obs_key)
        self.distillation = TwistDistillationLoss(teacher.world_model, student,
                                                  standardise_belief=config.standardise_belief)
        self.distillation.set_keys(teacher_observation=teacher_obs, student_observation=pixels_key)
        self.imagined = None
        if config.imagined:
            self.imagined = ImaginedAlignmentLoss(
                teacher.world_model, student, teacher.actor, horizon=config.horizon,
                action_noise_std=config.action_noise_std,
                max_starts=config.max_imagination_starts,
                standardise_belief=config.standardise_belief)
            self.imagined.set_keys(teacher_observation=teacher_obs,
                                   student_observation=pixels_key)
        self.pixels_key = pixels_key
        self.augment = None
        if config.shift_pad or config.rotate_deg:
            self.augment = torch.nn.Sequential(
                RandomShift(config.shift_pad, config.shift_per),
                RandomRotate(config.rotate_deg, config.shift_per))
        if augment is not None:  # e.g. ReadingNoise for a readout student's readings
            self.augment = augment if self.augment is None else torch.nn.Sequential(
                self.augment, augment)
        self.optim = torch.optim.Adam(student.parameters(), lr=config.lr)

    @property
    def device(self) -> torch.device:
        return module_device(self.student)

    def to(self, device: str | torch.device) -> TwistStudent:
        """Moves the student, the frozen teacher and the augmentation (its buffers, e.g.
        :class:`~simdist.modules.ReadingNoise`'s std) to ``device``; returns ``self``."""
        self.teacher.to(device)
        move_to_device([self.student], [self.optim], device)
        if self.augment is not None:
            self.augment.to(device)
        return self

    def start_from_teacher_rssm(self) -> int:
        """Copies into the student's RSSM every teacher RSSM tensor of the same name and
        shape (all of them when the embeddings match, e.g. a readout student's); returns
        how many. Not in TWIST, which starts the student from scratch: a student whose
        encoder gives the teacher's kind of embedding starts with the teacher's dynamics."""
        own = self.student.rssm.state_dict()
        same = {k: v for k, v in self.teacher.world_model.rssm.state_dict().items()
                if k in own and own[k].shape == v.shape}
        self.student.rssm.load_state_dict(same, strict=False)
        return len(same)

    def update(self, batch: TensorDictBase) -> dict[str, float]:
        """One student step on ``L_distil (+ L_imagined)``; teacher parameters never move."""
        batch = batch.to(self.device)
        if self.augment is not None:  # a shallow copy: the caller's images stay as they were
            batch = batch.copy()
            batch.set(self.pixels_key, self.augment(batch.get(self.pixels_key)))
        out = dict(self.distillation(batch).items())  # writes both posteriors into the batch
        total = out["loss_distillation"]
        if self.config.state_weight:
            decoded = self.teacher.world_model.decode(DreamerWorldModel.features(batch["student"]))
            state = (decoded - batch.get(("next", self.teacher.obs_key))).pow(2).sum(-1).mean()
            total = total + self.config.state_weight * state
            out["loss_state"] = state
        if self.config.action_weight:
            total = total + self.config.action_weight * self._action_mismatch(batch, out)
        if self.imagined is not None:
            imagined = self.imagined(batch)
            total = total + imagined["loss_imagined"]
            out.update(imagined.items())
        self.optim.zero_grad(set_to_none=True)
        total.backward()
        frozen = [*self.teacher.world_model.parameters(), *self.teacher.actor.parameters()]
        for p in frozen:  # the teacher is frozen: drop what reached it
            p.grad = None
        torch.nn.utils.clip_grad_norm_(self.student.parameters(), self.config.grad_clip)
        self.optim.step()
        # Read the figures after the step: on a GPU each .item() waits for the device.
        return {k: v.item() for k, v in out.items()}

    def _action_mismatch(self, batch: TensorDictBase, out: dict) -> torch.Tensor:
        """``||pi_T(student features) - pi_T(teacher features)||^2`` on the posteriors
        the distillation wrote into ``batch``; the gradient reaches the student only."""
        actor = self.teacher.actor
        with torch.no_grad():
            target = actor(DreamerWorldModel.features(batch["teacher"]))
        mismatch = action_error(actor(DreamerWorldModel.features(batch["student"])), target)
        out["loss_action"] = mismatch
        return mismatch

    def state_dict(self) -> dict:
        """The student's weights and optimiser (the teacher is saved with its own agent)."""
        return {"student": self.student.state_dict(), "optim": self.optim.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        """Restores :meth:`state_dict`'s output into a student built the same way.

        Raises:
            ValueError: if the saved student's readout has a fallback readout and this
                one has none, or the other way round (a student saved before the task's
                committed readout gained its fallback); the message says how to re-deploy.
        """
        own, saved = set(self.student.state_dict()), set(state["student"])
        fallback = sorted(k for k in own ^ saved if ".fallback." in f".{k}")
        if fallback:
            has = "has" if any(k in saved for k in fallback) else "has no"
            raise ValueError(
                f"the saved student's state readout {has} fallback readout and this "
                f"student's is the other way ({len(fallback)} keys differ, e.g. "
                f"{fallback[0]!r}): it was saved with another readout file. Build the "
                "student with the readout it was trained with, or re-deploy a finished "
                "run through today's file with experiments/twist_redeploy_readout.py")
        self.student.load_state_dict(state["student"])
        self.optim.load_state_dict(state["optim"])

    def policy(self, explore: bool = False, action_spec=None, actor=None) -> DreamerPolicy:
        """Pixels -> student latent -> teacher actor (uses ``self.make_primer()`` state).

        Args:
            explore: add the teacher's exploration noise (off for deployment).
            action_spec: the env's TorchRL action spec, checked to be ``[-1, 1]`` (the
                teacher actor's range; see :meth:`DreamerAgent.policy`).
            actor: another actor on the student's latent (e.g. one fitted by
                ``experiments/twist_dagger.py``); default: the teacher's, as in TWIST.
        """
        check_unit_box(action_spec)
        actor = self.teacher.actor if actor is None else actor
        return DreamerPolicy(self.student, actor, "pixels", obs_event_dims=3,
                             exploration_noise=self.teacher.config.exploration_noise,
                             explore=explore)

    def make_primer(self):
        return self.teacher.make_primer()  # same RSSM sizes, same state keys

    # -- self-describing checkpoints --------------------------------------------------
    def save(self, path: str | os.PathLike, optimisers: bool = True,
             meta: dict | None = None) -> Path:
        """Writes one self-describing file that deploys alone: the student, the teacher
        (its world model and actor, which the policy and the losses use; not its
        optimisers) and the configs. :meth:`load` needs no teacher checkpoint or recipe
        code. ``meta`` is free-form plain data (e.g. the task).

        Examples:
            >>> import tempfile
            >>> from simdist.agents import DreamerConfig
            >>> teacher = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
            >>> twist = TwistStudent(teacher, DreamerWorldModel.student(1, size="tiny"),
            ...                      TwistConfig(horizon=3))
            >>> loaded = TwistStudent.load(twist.save(Path(tempfile.mkdtemp()) / "s.pt"))
            >>> loaded.config.horizon, torch.equal(loaded.teacher.actor.net[0].weight,
            ...                                    teacher.actor.net[0].weight)
            (3, True)
        """
        config = {"twist": dataclasses.asdict(self.config),
                  "student": describe_dreamer_model(self.student),
                  "pixels_key": list(self.pixels_key) if isinstance(self.pixels_key, tuple)
                  else self.pixels_key,
                  "teacher": self.teacher.describe()}
        weights = {"student": self.student.state_dict(), "teacher": self.teacher.weights()}
        return ckpt_format.write_agent_checkpoint(
            path, "TwistStudent", config, weights,
            {"optim": self.optim.state_dict()} if optimisers else None, meta)

    @classmethod
    def from_checkpoint(cls, ckpt: dict, path="<checkpoint>", map_location=None) -> TwistStudent:
        """A student from a validated checkpoint dict (see :meth:`load`)."""
        config, weights = ckpt["config"], ckpt["weights"]
        teacher = DreamerAgent.from_config(ckpt_format.part(config, path, "teacher"), path)
        teacher.load_weights(ckpt_format.part(weights, path, "teacher"), path)
        student = ckpt_format.build("student", build_dreamer_model,
                                    ckpt_format.part(config, path, "student"), path)
        twist_config = ckpt_format.config_from_dict(
            TwistConfig, ckpt_format.part(config, path, "twist"), path, "TwistConfig")
        pixels_key = ckpt_format.part(config, path, "pixels_key")
        pixels_key = tuple(pixels_key) if isinstance(pixels_key, list) else pixels_key
        twist = cls(teacher, student, twist_config, pixels_key)
        ckpt_format.load_weights(student, ckpt_format.part(weights, path, "student"), path,
                                 "student")
        ckpt_format.load_optimisers(twist, ckpt, ("optim",), path)
        twist.checkpoint_meta = dict(ckpt.get("meta", {}))
        return twist.to(map_location) if map_location is not None else twist
