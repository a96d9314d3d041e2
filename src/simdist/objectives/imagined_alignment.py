"""TWIST imagined-rollout alignment (arXiv 2311.03622, Eq. 4 and Algorithm 1)."""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase

from simdist.modules.rssm import RSSMState
from simdist.modules.world_model import DreamerWorldModel
from simdist.objectives.common import sequence_batch
from simdist.objectives.distillation import TwistDistillationLoss, belief_distance


class ImaginedAlignmentLoss(TwistDistillationLoss):
    """``sum_i ||h_i^T - h_i^S||^2 + KL[p_S(z_i|h_i^S) || p_T(z_i|h_i^T)]`` over imagined steps.

    From the posterior states of a slice, the frozen teacher imagines ``horizon`` steps
    choosing actions with its actor plus Gaussian noise (``action_noise_std``); the
    student replays **exactly those actions** from its own posterior states of the same
    steps. Both share the sampling noise. Posterior states are read from
    ``("teacher"|"student", "belief"|"stoch")`` when :class:`TwistDistillationLoss`
    already wrote them (the student's still carry gradient), otherwise filtered here.

    Args:
        teacher: the frozen teacher world model.
        student: the student world model (same RSSM sizes as the teacher).
        teacher_actor: maps teacher features to actions in [-1, 1] (e.g. ``Actor``'s
            deterministic mode).
        horizon: imagined steps (TWIST: 15).
        action_noise_std: exploration noise on the teacher's actions (TWIST ablation: 0).
        standardise_belief: weigh each belief dimension by the inverse of the teacher's
            variance over the imagined batch (:func:`belief_distance`; not in TWIST).

    Examples:
        >>> import copy
        >>> from simdist.modules import Actor
        >>> teacher = DreamerWorldModel.teacher(state_dim=3, action_dim=1, size="tiny")
        >>> actor = Actor(teacher.rssm.feature_dim, 1, hidden=8)
        >>> loss = ImaginedAlignmentLoss(teacher, copy.deepcopy(teacher), actor, horizon=3)
        >>> x = torch.randn(2, 5, 3)  # a student identical to the teacher, on the same inputs
        >>> td = TensorDict({"action": torch.randn(2, 5, 1), "is_init": torch.zeros(2, 5, 1,
        ...     dtype=torch.bool), "next": {"state": x, "pixels": x}}, [2, 5])
        >>> loss(td)["loss_imagined"].item()
        0.0
    """

    # Subclasses TwistDistillationLoss for its keys, compatibility check and
    # ``filter_both``; ``forward`` computes Eq. 4 only.

    def __init__(self, teacher: DreamerWorldModel, student: DreamerWorldModel, teacher_actor,
                 horizon: int = 15, action_noise_std: float = 0.3, belief_weight: float = 1.0,
                 prior_weight: float = 1.0, max_starts: int | None = None,
                 check_inputs: bool = True, standardise_belief: bool = False):
        super().__init__(teacher, student, check_inputs=check_inputs,
                         standardise_belief=standardise_belief)
        if horizon < 1 or action_noise_std < 0:
            raise ValueError("horizon must be >= 1 and action_noise_std >= 0")
        self.teacher_actor = teacher_actor
        self.horizon, self.action_noise_std = horizon, action_noise_std
        self.weights, self.max_starts = (belief_weight, prior_weight), max_starts

    def _posteriors(self, td, B, T):
        if ("student", "belief") in td.keys(True):
            return (RSSMState(td.get(("teacher", "belief")), td.get(("teacher", "stoch"))),
                    RSSMState(td.get(("student", "belief")), td.get(("student", "stoch"))))
        t, s = self.filter_both(td)
        return RSSMState(t["belief"], t["stoch"]), RSSMState(s["belief"], s["stoch"])

    def forward(self, td: TensorDictBase) -> TensorDict:
        B, T = sequence_batch(td)
        teacher_post, student_post = self._posteriors(td, B, T)
        flat = lambda x: x.reshape(B * T, -1)  # noqa: E731
        t_state = RSSMState(flat(teacher_post.belief).detach(), flat(teacher_post.stoch).detach())
        s_state = RSSMState(flat(student_post.belief), flat(student_post.stoch))
        if self.max_starts and B * T > self.max_starts:
            index = torch.randperm(B * T, device=t_state.belief.device)[:self.max_starts]
            t_state = RSSMState(t_state.belief[index], t_state.stoch[index])
            s_state = RSSMState(s_state.belief[index], s_state.stoch[index])
        rssm = self.student.rssm
        noise = torch.rand(t_state.belief.shape[0], self.horizon, rssm.stoch, rssm.classes,
                           device=t_state.belief.device)
        with torch.no_grad():
            teacher = self.teacher.imagine_with_policy(
                t_state, self.teacher_actor, self.horizon,
                action_noise_std=self.action_noise_std, noise=noise)
        student = self.student.imagine(s_state, teacher["action"], noise=noise)
        belief = belief_distance(teacher["belief"], student["belief"], self.standardise_belief)
        prior = rssm.kl(student["prior_logits"], teacher["prior_logits"]).mean()
        wb, wp = self.weights
        return self.finish(TensorDict({
            "loss_imagined": wb * belief + wp * prior,
            "imagined_belief_mse": belief.detach(), "imagined_prior_kl": prior.detach()}, []))
