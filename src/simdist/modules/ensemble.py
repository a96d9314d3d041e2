"""Several SimDist world models planned with as one.

A finetuned SimDist model ranks the planner's candidate plans only loosely against the
true dynamics; independently trained models err partly independently, so the mean of
their predictions ranks better than any one of them (`docs/findings.md`, "Several
world models"). :class:`WorldModelEnsemble` puts K models side by side behind the verbs
and parts the planner and :class:`~simdist.agents.SimDistPolicy` use, so the recipe's
planner runs on it unchanged: each member encodes the history into its own latent and
rolls its own dynamics (the ensemble's latent is their concatenation); a candidate's
reward and terminal value, and the prior's proposal, are the members' means.

Training stays per member (each is a :class:`~simdist.modules.SimDistWorldModel` with
its own losses and optimisers); the ensemble is for planning.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from simdist.modules.checks import check_last_dims
from simdist.modules.simdist_model import LatentModelVerbs


class _PerMember(nn.Module):
    """Calls member ``i``'s part on slice ``i`` of a concatenated latent, then
    concatenates (latents) or averages (rewards, values, actions) the outputs; with
    ``pessimism`` > 0 an average is lowered by that many standard deviations over members."""

    def __init__(self, parts, latent_dim: int, combine: str, pessimism: float = 0.0):
        super().__init__()
        self.parts, self.member_dim, self.combine = nn.ModuleList(parts), latent_dim, combine
        self.latent_dim = latent_dim * len(parts)
        self.pessimism = pessimism

    def forward(self, latent: torch.Tensor, *rest: torch.Tensor) -> torch.Tensor:
        check_last_dims("latent", latent, (self.latent_dim,))
        outs = [part(z, *rest) for part, z in zip(self.parts, latent.split(self.member_dim, -1))]
        if self.combine == "cat":
            return torch.cat(outs, -1)
        outs = torch.stack(outs)
        if self.pessimism:
            return outs.mean(0) - self.pessimism * outs.std(0, correction=0)
        return outs.mean(0)


class _Encoders(nn.Module):
    """Every member's encoder on the same observation history, latents concatenated."""

    def __init__(self, encoders):
        super().__init__()
        self.parts = nn.ModuleList(encoders)
        first = encoders[0]
        self.history, self.obs_dim = first.history, first.obs_dim
        self.action_dim, self.input_dim = first.action_dim, first.input_dim
        self.context = first.context
        self.latent_dim = sum(e.latent_dim for e in encoders)

    def forward(self, window: torch.Tensor) -> torch.Tensor:
        return torch.cat([enc(window) for enc in self.parts], -1)

    def encode_sequence(self, obs: torch.Tensor, is_init: torch.Tensor,
                        actions: torch.Tensor | None = None) -> torch.Tensor:
        return torch.cat([enc.encode_sequence(obs, is_init, actions) for enc in self.parts], -1)

    def push(self, history, obs, previous_action, is_init) -> torch.Tensor:
        return self.parts[0].push(history, obs, previous_action, is_init)


class WorldModelEnsemble(LatentModelVerbs, nn.Module):
    """K SimDist world models as one model for planning.

    The ensemble's latent is the members' latents concatenated (``[..., K * L]``); its
    ``dynamics`` steps each member's slice with that member's dynamics; ``reward_head``,
    ``value_head`` and ``policy_head`` return the members' means. It offers the verbs of
    :class:`~simdist.modules.SimDistWorldModel` (``encode``, ``encode_sequence``,
    ``next``, ``rollout``, ``reward``, ``value``, ``policy``) and its attributes
    (``encoder.history``, ``encoder.obs_dim``, ``latent_dim``, ``action_dim``), so
    :meth:`LatentMPPIPlanner.from_world_model <simdist.modules.LatentMPPIPlanner.from_world_model>`
    and ``SimDistAgent(ensemble, planner_config=...).policy(...)`` plan with it unchanged.
    Members keep their own weights: finetune each one (e.g. its own
    ``SimDistAgent.finetune_update``), then plan with the ensemble.

    Args:
        members: SimDist world models with the same observation size, history, latent
            size and action size (e.g. the same config pretrained from different seeds).
        pessimism: score a candidate by the members' mean reward and value *minus* this
            many standard deviations over members (a lower confidence bound: plans the
            members disagree on rank lower). 0 (default): the plain mean.

    Raises:
        ValueError: fewer than one member, members that disagree on those sizes, or a
            negative or non-finite ``pessimism``.

    Examples:
        >>> from simdist.modules import SimDistWorldModel, LatentMPPIPlanner, PlannerConfig
        >>> members = [SimDistWorldModel.build(10, 3, size="tiny") for _ in range(3)]
        >>> ensemble = WorldModelEnsemble(members)
        >>> z = ensemble.encode(torch.randn(4, 2, 10))       # history 2 of the tiny size
        >>> z.shape, ensemble.reward(z, torch.zeros(4, 3)).shape
        (torch.Size([4, 48]), torch.Size([4, 1]))
        >>> planner = LatentMPPIPlanner.from_world_model(
        ...     ensemble, PlannerConfig(horizon=3, num_samples=16, num_elites=4))
    """

    def __init__(self, members, pessimism: float = 0.0):
        super().__init__()
        members = list(members)
        if not members:
            raise ValueError("WorldModelEnsemble needs at least one member")
        if not (math.isfinite(pessimism) and pessimism >= 0):
            raise ValueError(f"pessimism must be a finite number >= 0, got {pessimism}")
        first = members[0]

        def sizes(m):
            return (m.encoder.obs_dim, m.encoder.history, m.latent_dim, m.action_dim,
                    m.encoder.action_dim)

        for i, m in enumerate(members[1:], 1):
            if sizes(m) != sizes(first):
                raise ValueError(
                    f"ensemble member {i} has (obs_dim, history, latent_dim, action_dim, "
                    f"previous-action inputs) "
                    f"{sizes(m)}, member 0 has {sizes(first)}: members must share them")
        L = first.latent_dim
        self.members = nn.ModuleList(members)
        self.encoder = _Encoders([m.encoder for m in members])
        self.dynamics = _PerMember([m.dynamics for m in members], L, "cat")
        self.reward_head = _PerMember([m.reward_head for m in members], L, "mean", pessimism)
        self.value_head = _PerMember([m.value_head for m in members], L, "mean", pessimism)
        self.pessimism = pessimism
        self.policy_head = _PerMember([m.policy_head for m in members], L, "mean")
        self.latent_dim, self.action_dim = L * len(members), first.action_dim

    def __len__(self) -> int:
        return len(self.members)
