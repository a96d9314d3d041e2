"""SimDist's latent world model: history encoder, latent dynamics, reward/value/policy heads.

No reconstruction anywhere: the latent is shaped only by consistency (dynamics must
predict the encoder's future latents), reward, value and behaviour cloning. SimNorm on the
encoder and dynamics outputs (TD-MPC2) keeps the latent bounded.
"""

from __future__ import annotations

import copy

import torch
from torch import nn

from simdist.modules.checks import check_last_dims
from simdist.modules.encoders import HistoryEncoder, mlp, simnorm
from simdist.modules.heads import PolicyPrior, ScalarHead

SIMDIST_SIZES = {
    "tiny": dict(latent_dim=16, hidden=32, history=2, simnorm_groups=4),
    "small": dict(latent_dim=64, hidden=256, history=4, simnorm_groups=8),
    # The paper's width on the CPU default's 4-step history: on the slippery slope it is the
    # one change that moved the finetuned planner (docs/findings.md, issue 21 sections).
    "wide": dict(latent_dim=64, hidden=512, history=4, simnorm_groups=8),
    "paper": dict(latent_dim=64, hidden=512, history=25, simnorm_groups=8),
}


DYNAMICS_RESIDUALS = ("additive", "logit")


class MLPDynamics(nn.Module):
    """MLP transition on SimNorm latents (swappable part).

    ``residual="additive"``: ``z' = norm(z + f([z, a]))``, the form every model before
    2026-12-03 was trained with. Under SimNorm (a softmax per group) this is *not* an
    identity residual: ``z`` is a probability vector, and ``f = 0`` gives ``softmax(z)``,
    a blurred copy, so the MLP must rebuild the whole next latent each step (in effect
    TD-MPC2's ``norm(f([z, a]))`` with ``z`` as an extra logit bias).

    ``residual="logit"``: ``z' = norm(log z + f([z, a]))`` with ``f``'s last layer
    zero-initialised: ``softmax(log z) = z`` within each group, so an untrained dynamics
    predicts "no change" exactly and ``f`` learns the change, in the logits. Without
    SimNorm (``simnorm_groups=None``) both forms are the plain residual ``z + f``.

    Examples:
        >>> dyn = MLPDynamics(latent_dim=16, action_dim=2, hidden=32, simnorm_groups=4)
        >>> dyn(torch.rand(5, 16), torch.zeros(5, 2)).shape
        torch.Size([5, 16])
        >>> z = simnorm(torch.randn(5, 16), 4)
        >>> logit = MLPDynamics(16, 2, hidden=32, simnorm_groups=4, residual="logit")
        >>> torch.allclose(logit(z, torch.zeros(5, 2)), z, atol=1e-6)  # starts at no change
        True
    """

    def __init__(self, latent_dim: int, action_dim: int, hidden: int = 256, layers: int = 2,
                 simnorm_groups: int | None = 8, residual: str = "additive"):
        super().__init__()
        if residual not in DYNAMICS_RESIDUALS:
            raise ValueError(f"unknown dynamics residual {residual!r}; valid: "
                             f"{', '.join(DYNAMICS_RESIDUALS)}")
        self.latent_dim, self.action_dim, self.simnorm_groups = latent_dim, action_dim, simnorm_groups
        self.residual = residual
        # SiLU rather than TD-MPC2's Mish: same smoothness, ~7x cheaper on CPU (32 vs 230 us
        # per [128, 256] activation here), and the planner evaluates this thousands of times.
        self.net = mlp(latent_dim + action_dim, latent_dim, hidden, layers, activation=nn.SiLU)
        if residual == "logit":
            last = [m for m in self.net.modules() if isinstance(m, nn.Linear)][-1]
            nn.init.zeros_(last.weight)
            nn.init.zeros_(last.bias)

    def reset_parameters(self) -> None:
        """Fresh weights, initialised as at construction (an ensemble's new member)."""
        for module in self.net.modules():
            if isinstance(module, nn.Linear):
                module.reset_parameters()
        if self.residual == "logit":
            last = [m for m in self.net.modules() if isinstance(m, nn.Linear)][-1]
            nn.init.zeros_(last.weight)
            nn.init.zeros_(last.bias)

    def forward(self, latent: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        change = self.net(torch.cat([latent, action], -1))
        if not self.simnorm_groups:
            return latent + change
        if self.residual == "logit":
            # SimNorm latents are strictly positive; the floor only guards log(0) after
            # an underflowing softmax (exp(-16) is below anything a group of 8 carries).
            base = torch.log(latent.float().clamp_min(1e-7))
            return simnorm(base + change, self.simnorm_groups)
        return simnorm(latent + change, self.simnorm_groups)


class LatentModelVerbs:
    """The verbs of a SimDist latent model over its parts ``encoder``, ``dynamics``,
    ``reward_head``, ``value_head`` and ``policy_head`` (shared by
    :class:`SimDistWorldModel` and :class:`~simdist.modules.WorldModelEnsemble`)."""

    def encode(self, window: torch.Tensor) -> torch.Tensor:
        return self.encoder(window)

    def encode_sequence(self, obs: torch.Tensor, is_init: torch.Tensor,
                        actions: torch.Tensor | None = None) -> torch.Tensor:
        """Latents of ``[B, T, D]`` sequences; ``actions [B, T, A]`` are read (as each
        step's previous action) only by an encoder built with ``previous_action=True``."""
        return self.encoder.encode_sequence(obs, is_init, actions)

    def next(self, latent: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.dynamics(latent, action)

    def rollout(self, latent: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        """Predicts ``z_{1..H}`` from ``z_0 [..., L]`` and ``actions [..., H, A]``."""
        check_last_dims("latent", latent, (self.latent_dim,))
        check_last_dims("actions", actions, (self.action_dim,))
        out = []
        for i in range(actions.shape[-2]):
            latent = self.dynamics(latent, actions[..., i, :])
            out.append(latent)
        return torch.stack(out, -2)

    def reward(self, latent: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.reward_head(latent, action)

    def value(self, latent: torch.Tensor) -> torch.Tensor:
        return self.value_head(latent)

    def policy(self, latent: torch.Tensor) -> torch.Tensor:
        return self.policy_head(latent)


class SimDistWorldModel(LatentModelVerbs, nn.Module):
    """Encoder, dynamics, reward ``r(z, a)``, value ``V(z)`` and policy prior ``pi(z)``.

    Verbs (TD-MPC2 style): :meth:`encode`, :meth:`encode_sequence`, :meth:`next`,
    :meth:`rollout`, :meth:`reward`, :meth:`value`, :meth:`policy`. Parts are attributes
    (``encoder``, ``dynamics``, ``reward_head``, ``value_head``, ``policy_head``) so
    losses can train or freeze them by name; :meth:`parts` lists them.

    Examples:
        >>> wm = SimDistWorldModel.build(obs_dim=10, action_dim=3, size="tiny")
        >>> obs = torch.randn(4, 7, 10); is_init = torch.zeros(4, 7, dtype=torch.bool)
        >>> z = wm.encode_sequence(obs, is_init)
        >>> wm.rollout(z[:, 0], torch.zeros(4, 5, 3)).shape
        torch.Size([4, 5, 16])
        >>> wm.value(z).shape, wm.reward(z, torch.zeros(4, 7, 3)).shape
        (torch.Size([4, 7, 1]), torch.Size([4, 7, 1]))
    """

    PARTS = ("encoder", "dynamics", "reward_head", "value_head", "policy_head")

    def __init__(self, encoder: HistoryEncoder, dynamics: nn.Module, reward_head: nn.Module,
                 value_head: nn.Module, policy_head: nn.Module):
        super().__init__()
        self.encoder, self.dynamics = encoder, dynamics
        self.reward_head, self.value_head, self.policy_head = reward_head, value_head, policy_head
        self.latent_dim, self.action_dim = encoder.latent_dim, dynamics.action_dim

    @classmethod
    def build(cls, obs_dim: int, action_dim: int, size: str = "small",
              dynamics: nn.Module | None = None, **overrides) -> SimDistWorldModel:
        """Builds a model from the size table (``tiny``, ``small``, ``wide``, ``paper``).

        ``overrides`` replace the size's entries (``latent_dim``, ``hidden``, ``history``,
        ``simnorm_groups``) or add ``ignored_inputs`` (encoder inputs zeroed),
        ``dynamics_hidden`` (the dynamics MLP's width; default ``hidden``: the one part
        SimDist finetunes may be given more capacity than the frozen ones),
        ``dynamics_residual`` (:class:`MLPDynamics`' ``residual``, default ``"additive"``),
        ``prior_bounds`` (``(low, high)``: the policy prior's output box, see
        :class:`~simdist.modules.PolicyPrior`; default [-1, 1]) and
        ``previous_action`` (``True``: the encoder reads the action sent one step before
        each observation of its window, see :class:`~simdist.modules.HistoryEncoder`).
        """
        if size not in SIMDIST_SIZES:
            raise ValueError(f"unknown model size {size!r}; valid: {', '.join(SIMDIST_SIZES)}")
        s = {**SIMDIST_SIZES[size], **overrides}
        latent, hidden, groups = s["latent_dim"], s["hidden"], s["simnorm_groups"]
        dynamics_hidden = s.get("dynamics_hidden") or hidden
        return cls(
            HistoryEncoder(obs_dim, s["history"], latent, hidden, simnorm_groups=groups,
                           ignored_inputs=s.get("ignored_inputs", ()),
                           action_dim=action_dim if s.get("previous_action") else 0),
            dynamics or MLPDynamics(latent, action_dim, dynamics_hidden, simnorm_groups=groups,
                                    residual=s.get("dynamics_residual") or "additive"),
            ScalarHead(latent + action_dim, hidden, activation=nn.SiLU),
            ScalarHead(latent, hidden, activation=nn.SiLU),
            PolicyPrior(latent, action_dim, hidden,
                        **dict(zip(("action_low", "action_high"), s.get("prior_bounds") or ()))),
        )

    def parts(self) -> dict[str, nn.Module]:
        return {name: getattr(self, name) for name in self.PARTS}

    def with_dynamics(self, dynamics: nn.Module) -> SimDistWorldModel:
        """A model that *shares* this one's encoder and heads (the same modules, not
        copies) and steps with ``dynamics``: a member of a dynamics ensemble.

        Examples:
            >>> wm = SimDistWorldModel.build(obs_dim=10, action_dim=3, size="tiny")
            >>> other = wm.with_dynamics(MLPDynamics(16, 3, hidden=32, simnorm_groups=4))
            >>> other.encoder is wm.encoder, other.dynamics is wm.dynamics
            (True, False)
        """
        sizes = (getattr(dynamics, "latent_dim", self.latent_dim),
                 getattr(dynamics, "action_dim", self.action_dim))
        if sizes != (self.latent_dim, self.action_dim):
            raise ValueError(f"dynamics of (latent_dim, action_dim) {sizes} cannot step this "
                             f"model's latents: it has {(self.latent_dim, self.action_dim)}")
        return type(self)(self.encoder, dynamics, self.reward_head, self.value_head,
                          self.policy_head)

    def fresh_dynamics(self) -> nn.Module:
        """A copy of this model's dynamics module with freshly initialised weights."""
        dynamics = copy.deepcopy(self.dynamics)
        if isinstance(dynamics, MLPDynamics):  # its own initialisation (e.g. a zero last layer)
            dynamics.reset_parameters()
            return dynamics
        for module in dynamics.modules():
            if module is not dynamics and hasattr(module, "reset_parameters"):
                module.reset_parameters()
        return dynamics
