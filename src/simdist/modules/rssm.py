"""Recurrent state-space model with categorical latents (DreamerV2/V3 style).

Why not TorchRL's ``RSSMPriorV3`` / ``RSSMPosteriorV3`` / ``RSSMRolloutV3``: the rollout
steps a TensorDict per time step (slow on CPU at batch 16 x 50), and sampling noise is
drawn inside the modules (only a private ``_uniform`` argument exposes it). TWIST needs
teacher and student to share sampling noise (so a student identical to the teacher has
exactly zero distillation loss) and per-step ``is_init`` resets inside one tensor-level
scan. This module keeps DreamerV3's structure (GRU sequence model, categorical prior and
posterior with straight-through samples and unimix) with those two things explicit.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from simdist.modules.checks import check_last_dims
from simdist.modules.encoders import mlp


@dataclass
class RSSMState:
    """Deterministic belief ``h`` and stochastic one-hot sample ``z`` (flattened).

    Examples:
        >>> rssm = RSSM(embed_dim=8, action_dim=2, deter_dim=16, stoch=4, classes=4, hidden_dim=16)
        >>> belief, logits = rssm.prior_step(rssm.initial((3,)), torch.zeros(3, 2))
        >>> state = RSSMState(belief, rssm.sample(logits))
        >>> state.stoch.shape, state.features().shape, state.detach().belief.requires_grad
        (torch.Size([3, 16]), torch.Size([3, 32]), False)
    """

    belief: torch.Tensor
    stoch: torch.Tensor

    def features(self) -> torch.Tensor:
        return torch.cat([self.belief, self.stoch], -1)

    def detach(self) -> RSSMState:
        return RSSMState(self.belief.detach(), self.stoch.detach())


class RSSM(nn.Module):
    """``h_t = f(h_{t-1}, z_{t-1}, a_{t-1})``, prior ``p(z_t | h_t)``, posterior ``q(z_t | h_t, e_t)``.

    Args:
        embed_dim: size of the encoder output ``e_t``.
        action_dim: action size.
        deter_dim: GRU belief size.
        stoch: number of categorical variables.
        classes: classes per categorical variable.
        hidden_dim: width of the input/prior/posterior MLPs.
        unimix: uniform mixture in the categorical probabilities (DreamerV3: 0.01).

    Examples:
        >>> rssm = RSSM(embed_dim=8, action_dim=2, deter_dim=16, stoch=4, classes=4, hidden_dim=16)
        >>> embed, action = torch.randn(3, 5, 8), torch.randn(3, 5, 2)
        >>> is_first = torch.zeros(3, 5, dtype=torch.bool)
        >>> out = rssm.observe(embed, action, is_first)
        >>> out["belief"].shape, out["posterior_logits"].shape
        (torch.Size([3, 5, 16]), torch.Size([3, 5, 4, 4]))
    """

    def __init__(self, embed_dim: int, action_dim: int, deter_dim: int = 200, stoch: int = 32,
                 classes: int = 32, hidden_dim: int = 200, unimix: float = 0.01):
        super().__init__()
        if not 0 <= unimix < 1:
            raise ValueError(f"unimix must be in [0, 1), got {unimix}")
        self.embed_dim, self.action_dim, self.deter_dim = embed_dim, action_dim, deter_dim
        self.stoch, self.classes, self.unimix = stoch, classes, unimix
        self.stoch_dim = stoch * classes
        self.feature_dim = deter_dim + self.stoch_dim
        self.input_net = nn.Sequential(nn.Linear(self.stoch_dim + action_dim, hidden_dim),
                                       nn.LayerNorm(hidden_dim), nn.ELU())
        self.gru = nn.GRUCell(hidden_dim, deter_dim)
        self.prior_net = mlp(deter_dim, self.stoch_dim, hidden_dim, 1)
        self.posterior_net = mlp(deter_dim + embed_dim, self.stoch_dim, hidden_dim, 1)

    # -- distributions ------------------------------------------------------------------
    def log_probs(self, logits: torch.Tensor) -> torch.Tensor:
        """Log-probabilities with the unimix floor, ``[..., stoch, classes]``."""
        probs = torch.softmax(logits, -1)
        if self.unimix:
            probs = (1 - self.unimix) * probs + self.unimix / self.classes
        return torch.log(probs)

    def sample(self, logits: torch.Tensor, noise: torch.Tensor | None = None) -> torch.Tensor:
        """Straight-through one-hot sample, flattened to ``[..., stoch * classes]``.

        ``noise`` are uniforms in (0, 1) of ``logits``' shape (Gumbel-max trick); pass the
        same noise to two models to make them draw identical samples.
        """
        log_p = self.log_probs(logits)
        if noise is None:
            noise = torch.rand_like(log_p)
        gumbel = -torch.log(-torch.log(noise.clamp(1e-10, 1 - 1e-7)))
        index = (log_p + gumbel).argmax(-1)
        one_hot = torch.nn.functional.one_hot(index, self.classes).to(log_p.dtype)
        probs = log_p.exp()
        return (one_hot + (probs - probs.detach())).flatten(-2)  # exact one-hot forward

    def kl(self, logits_p: torch.Tensor, logits_q: torch.Tensor) -> torch.Tensor:
        """``KL[p || q]`` summed over the categorical variables, ``[...]``."""
        log_p, log_q = self.log_probs(logits_p), self.log_probs(logits_q)
        return (log_p.exp() * (log_p - log_q)).sum((-2, -1))

    def _logits(self, net: nn.Module, x: torch.Tensor) -> torch.Tensor:
        return net(x).unflatten(-1, (self.stoch, self.classes))

    # -- single steps -------------------------------------------------------------------
    def initial(self, batch_shape, device=None) -> RSSMState:
        zeros = lambda n: torch.zeros(*batch_shape, n, device=device)  # noqa: E731
        return RSSMState(zeros(self.deter_dim), zeros(self.stoch_dim))

    def prior_step(self, state: RSSMState, action: torch.Tensor):
        """Advances the belief with ``action``; returns ``(belief, prior_logits)``."""
        x = self.input_net(torch.cat([state.stoch, action], -1))
        lead = x.shape[:-1]
        belief = self.gru(x.reshape(-1, x.shape[-1]),
                          state.belief.reshape(-1, self.deter_dim)).reshape(*lead, -1)
        return belief, self._logits(self.prior_net, belief)

    def posterior_logits(self, belief: torch.Tensor, embed: torch.Tensor) -> torch.Tensor:
        return self._logits(self.posterior_net, torch.cat([belief, embed], -1))

    # -- sequences ----------------------------------------------------------------------
    def observe(self, embed: torch.Tensor, prev_action: torch.Tensor, is_first: torch.Tensor,
                state: RSSMState | None = None, noise: torch.Tensor | None = None) -> dict:
        """Filters ``[B, T, ...]`` sequences into posterior states.

        Step ``t`` advances the belief with ``prev_action[:, t]`` (the action that led to
        the observation embedded in ``embed[:, t]``), then conditions on ``embed[:, t]``.
        Where ``is_first[:, t]`` is set, the state entering step ``t`` and
        ``prev_action[:, t]`` (the previous episode's last action) are reset to zero, so
        sequences that cross an episode boundary never leak state across it. Without
        ``state`` the slice starts from the zero state.

        Returns:
            dict of ``belief [B,T,deter]``, ``stoch [B,T,stoch*classes]``,
            ``prior_logits`` and ``posterior_logits`` ``[B,T,stoch,classes]``.
        """
        check_last_dims("embed", embed, (self.embed_dim,))
        check_last_dims("action", prev_action, (self.action_dim,))
        B, T = embed.shape[:2]
        if is_first.shape != (B, T):
            raise ValueError(f"'is_init' must have shape {(B, T)}, got {tuple(is_first.shape)}")
        state = state or self.initial((B,), embed.device)
        keep = (~is_first).to(embed.dtype)[..., None]
        outs = {"belief": [], "stoch": [], "prior_logits": [], "posterior_logits": []}
        for t in range(T):
            state = self.filter_step(state, prev_action[:, t], embed[:, t], keep[:, t],
                                     None if noise is None else noise[:, t], outs)
        return {k: torch.stack(v, 1) for k, v in outs.items()}

    def filter_step(self, state: RSSMState, prev_action: torch.Tensor, embed: torch.Tensor,
                    keep: torch.Tensor | None = None, noise: torch.Tensor | None = None,
                    record: dict | None = None) -> RSSMState:
        """One filtering step (deployment): zero the state and ``prev_action`` where
        ``keep == 0`` (an episode's first step), predict, correct."""
        if keep is not None:
            state = RSSMState(state.belief * keep, state.stoch * keep)
            prev_action = prev_action * keep
        belief, prior_logits = self.prior_step(state, prev_action)
        post_logits = self.posterior_logits(belief, embed)
        stoch = self.sample(post_logits, noise)
        if record is not None:
            for key, value in zip(record, (belief, stoch, prior_logits, post_logits)):
                record[key].append(value)
        return RSSMState(belief, stoch)

    def imagine(self, state: RSSMState, actions: torch.Tensor,
                noise: torch.Tensor | None = None) -> dict:
        """Rolls the prior forward with given ``actions [..., H, A]`` from ``state``.

        Returns ``belief``, ``stoch`` and ``prior_logits`` for the ``H`` imagined steps
        (step ``i`` results from ``actions[..., i]``).
        """
        check_last_dims("actions", actions, (self.action_dim,))
        outs = {"belief": [], "stoch": [], "prior_logits": []}
        for i in range(actions.shape[-2]):
            belief, logits = self.prior_step(state, actions[..., i, :])
            stoch = self.sample(logits, None if noise is None else noise[..., i, :, :])
            state = RSSMState(belief, stoch)
            for key, value in zip(outs, (belief, stoch, logits)):
                outs[key].append(value)
        return {k: torch.stack(v, -3 if k == "prior_logits" else -2) for k, v in outs.items()}

    def imagine_with_policy(self, state: RSSMState, policy, horizon: int,
                            action_noise_std: float = 0.0, noise: torch.Tensor | None = None,
                            generator: torch.Generator | None = None) -> dict:
        """Imagines ``horizon`` steps choosing actions with ``policy(features)``.

        Gaussian ``action_noise_std`` is added to each action (TWIST's exploration noise
        for imagined-rollout alignment) and the result clipped to [-1, 1]. Returns the
        same keys as :meth:`imagine` plus ``action [..., H, A]``, the exact actions used.
        """
        outs = {"belief": [], "stoch": [], "prior_logits": [], "action": []}
        for i in range(horizon):
            action = policy(state.features())
            if action_noise_std:
                eps = torch.randn(action.shape, generator=generator, device=action.device)
                action = (action + action_noise_std * eps).clamp(-1, 1)
            belief, logits = self.prior_step(state, action)
            stoch = self.sample(logits, None if noise is None else noise[..., i, :, :])
            state = RSSMState(belief, stoch)
            for key, value in zip(outs, (belief, stoch, logits, action)):
                outs[key].append(value)
        return {k: torch.stack(v, -3 if k == "prior_logits" else -2) for k, v in outs.items()}
