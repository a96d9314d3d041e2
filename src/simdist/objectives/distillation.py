"""TWIST teacher-student distillation (arXiv 2311.03622, Eq. 3)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey

from simdist.modules.encoders import PixelEncoder
from simdist.modules.world_model import DreamerWorldModel
from simdist.objectives.common import SimdistLoss, sequence_batch


def belief_distance(teacher: torch.Tensor, student: torch.Tensor,
                    standardise: bool = False) -> torch.Tensor:
    """``||h^T - h^S||^2`` summed over the last dimension, averaged over the others.

    With ``standardise``, each dimension's squared error is divided by the teacher's
    variance of that dimension over the batch (every leading dimension pooled; a constant,
    no gradient) and multiplied by the mean of those variances, so a batch whose
    dimensions all have the same variance gives the plain distance: dimensions that carry
    small-variance information weigh as much as the large ones. Variances are floored at
    ``STANDARDISE_FLOOR`` x their mean (a dimension's weight is at most 1 / floor).

    Examples:
        >>> t = torch.tensor([[0.0, 0.0], [2.0, 0.2]])  # variances 1 and 0.01, mean 0.505
        >>> s = torch.tensor([[0.0, 0.1], [2.0, 0.2]])  # wrong in the small dimension only
        >>> round(belief_distance(t, s).item(), 4)  # 0.1^2 / 2
        0.005
        >>> round(belief_distance(t, s, standardise=True).item(), 4)  # 0.01 * 0.505/0.01 / 2
        0.2525
    """
    squared = (teacher - student).pow(2)
    if standardise:
        with torch.no_grad():
            var = teacher.reshape(-1, teacher.shape[-1]).var(0, unbiased=False)
            tiny = torch.finfo(var.dtype).tiny  # all-constant batch: every weight 1
            mean = var.mean().clamp_min(tiny)
            weight = mean / var.clamp_min((STANDARDISE_FLOOR * mean).clamp_min(tiny))
        squared = squared * weight
    return squared.sum(-1).mean()


STANDARDISE_FLOOR = 0.01


def check_compatible(teacher: DreamerWorldModel, student: DreamerWorldModel) -> None:
    t, s = teacher.rssm, student.rssm
    for field in ("deter_dim", "stoch", "classes", "action_dim", "unimix"):
        if getattr(t, field) != getattr(s, field):
            raise ValueError(f"teacher and student RSSMs differ in {field}: "
                             f"{getattr(t, field)} vs {getattr(s, field)}; TWIST distils "
                             "latent to latent, so they must match")


class TwistDistillationLoss(SimdistLoss):
    """``||h^T - h^S||^2 + KL[p_S(z|h^S) || p_T(z|h^T)] + KL[q_S(z|h^S,o) || q_T(z|h^T,s)]``.

    Teacher (privileged state) and student (images of the same steps) filter the same
    slice; the teacher runs under ``torch.no_grad`` so it is frozen by construction.
    Both draw their latent samples from **the same noise**, so a student that computes
    exactly what the teacher computes has exactly zero loss. Terms are summed over
    feature/latent dimensions and averaged over batch and time (the paper sums over time;
    this only rescales the learning rate). The posterior states of both are written into
    the input TensorDict under ``("teacher", ...)`` / ``("student", ...)`` so
    :class:`ImaginedAlignmentLoss` can start from them without refiltering.

    ``standardise_belief=True`` (not in TWIST; default off) weighs each dimension of the
    belief distance by the inverse of the teacher's batch variance of that dimension
    (:func:`belief_distance`), so small-variance dimensions count as much as large ones.

    Examples:
        >>> import copy
        >>> teacher = DreamerWorldModel.teacher(state_dim=3, action_dim=1, size="tiny")
        >>> student = copy.deepcopy(teacher)
        >>> loss = TwistDistillationLoss(teacher, student)
        >>> loss.set_keys(student_observation=("next", "state"))  # identical inputs
        >>> td = TensorDict({"action": torch.randn(2, 5, 1),
        ...                  "is_init": torch.zeros(2, 5, 1, dtype=torch.bool),
        ...                  "next": {"state": torch.randn(2, 5, 3)}}, [2, 5])
        >>> loss(td)["loss_distillation"].item()
        0.0
    """

    @dataclass
    class _AcceptedKeys:
        teacher_observation: NestedKey = ("next", "state")
        student_observation: NestedKey = ("next", "pixels")
        action: NestedKey = "action"
        is_init: NestedKey = "is_init"

    default_keys = _AcceptedKeys

    def __init__(self, teacher: DreamerWorldModel, student: DreamerWorldModel,
                 belief_weight: float = 1.0, prior_weight: float = 1.0,
                 posterior_weight: float = 1.0, check_inputs: bool = True,
                 standardise_belief: bool = False):
        super().__init__(check_inputs)
        check_compatible(teacher, student)
        self.teacher, self.student = teacher, student
        self.weights = (belief_weight, prior_weight, posterior_weight)
        self.standardise_belief = standardise_belief

    def trainable_parameters(self):
        return list(self.student.parameters())

    def filter_both(self, td: TensorDictBase) -> tuple[dict, dict]:
        """Teacher (no grad) and student posterior states of a slice, with shared noise."""
        B, T = sequence_batch(td)
        action = self.read(td, "action")
        is_init = self.read_flag(td, "is_init", (B, T))
        rssm = self.student.rssm
        noise = torch.rand(B, T, rssm.stoch, rssm.classes, device=action.device)
        with torch.no_grad():
            teacher = self.teacher.observe(self.read(td, "teacher_observation"), action,
                                           is_init, noise=noise)
        observation = (self.read_pixels(td, "student_observation")
                       if isinstance(self.student.encoder, PixelEncoder)
                       else self.read(td, "student_observation"))
        student = self.student.observe(observation, action, is_init, noise=noise)
        return teacher, student

    def forward(self, td: TensorDictBase) -> TensorDict:
        teacher, student = self.filter_both(td)
        rssm = self.student.rssm
        belief = belief_distance(teacher["belief"], student["belief"], self.standardise_belief)
        prior = rssm.kl(student["prior_logits"], teacher["prior_logits"]).mean()
        posterior = rssm.kl(student["posterior_logits"], teacher["posterior_logits"]).mean()
        wb, wp, wq = self.weights
        for name, states in (("teacher", teacher), ("student", student)):
            td.set((name, "belief"), states["belief"])
            td.set((name, "stoch"), states["stoch"])
        return self.finish(TensorDict({
            "loss_distillation": wb * belief + wp * prior + wq * posterior,
            "belief_mse": belief.detach(), "prior_kl": prior.detach(),
            "posterior_kl": posterior.detach()}, []))
