"""SimDist world-model pretraining and dynamics-only finetuning (docs/methods.md 1.3, 1.5)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey
from torch import nn

from simdist.modules.encoders import simnorm
from simdist.modules.simdist_model import SimDistWorldModel
from simdist.objectives.common import SimdistLoss, sequence_batch


def rollout_windows(model: SimDistWorldModel, latents: torch.Tensor, actions: torch.Tensor,
                    is_init: torch.Tensor, horizon: int, dynamics: nn.Module | None = None):
    """Predicts ``horizon`` latents from every start of ``[B, T]`` slices in parallel.

    ``dynamics`` (default: the model's own) steps the latent; any module with the same
    call as :class:`~simdist.modules.MLPDynamics` (e.g. another member of a dynamics
    ensemble on the same encoder).

    Returns ``(predicted [B, S, H, L], targets [B, S, H, L], mask [B, S, H])`` with
    ``S = T - horizon`` starts; ``mask`` drops targets on or after an episode start
    (the rollout would cross the boundary) and every start or target whose encoder window
    would reach before the slice (see :func:`complete_windows`).
    """
    B, T, L = latents.shape
    S = T - horizon
    if S < 1:
        raise ValueError(f"slices of length {T} are too short for horizon {horizon}: "
                         f"need at least {horizon + 1} steps")
    windows = actions.unfold(1, horizon, 1)[:, :S].transpose(-1, -2)        # [B, S, H, A]
    stepper = model if dynamics is None else model.with_dynamics(dynamics)
    predicted = stepper.rollout(latents[:, :S], windows)                     # [B, S, H, L]
    targets = latents.unfold(1, horizon, 1)[:, 1:S + 1].transpose(-1, -2)   # [B, S, H, L]
    crosses = is_init.unfold(1, horizon, 1)[:, 1:S + 1]                     # [B, S, H]
    mask = torch.cumprod((~crosses).to(latents.dtype), -1)
    complete = complete_windows(is_init, model.encoder.context).to(latents.dtype)
    target_ok = complete.unfold(1, horizon, 1)[:, 1:S + 1]
    return predicted, targets, mask * complete[:, :S, None] * target_ok


def complete_windows(is_init: torch.Tensor, history: int) -> torch.Tensor:
    """``[B, T]``: whether step ``t``'s encoder window is what the robot would see.

    ``history`` is the number of steps a window reads (the encoder's ``context``: its
    history, plus one when it reads each step's previous action). A window is complete
    when it fits inside the slice (``t >= history - 1``) or an
    episode starts at or before ``t`` inside the slice (then its clamped window is exactly
    the deployment one). Otherwise the slice cut off real history, and training on it
    would teach the encoder windows it never sees when deployed.
    """
    T = is_init.shape[1]
    fits = torch.arange(T, device=is_init.device) >= history - 1
    started = torch.cummax(is_init.to(torch.int8), 1).values.bool()
    return fits[None] | started


CONSISTENCY_KINDS = ("squared", "kl")


def check_consistency(kind: str, simnorm_groups: int | None) -> None:
    """Refuses an unknown consistency ``kind``, and ``"kl"`` on a latent without SimNorm."""
    if kind not in CONSISTENCY_KINDS:
        raise ValueError(f"unknown consistency {kind!r}; valid: {', '.join(CONSISTENCY_KINDS)}")
    if kind == "kl" and not simnorm_groups:
        raise ValueError("consistency 'kl' needs a SimNorm latent (simnorm_groups): it "
                         "compares each group as a categorical distribution")


def consistency_error(predicted: torch.Tensor, targets: torch.Tensor,
                      simnorm_groups: int | None, kind: str = "squared") -> torch.Tensor:
    """Per-prediction consistency error ``[...]`` of latents ``[..., L]`` (targets detached).

    ``"squared"``: ``||z^ - z||^2`` summed over the latent's dimensions (TD-MPC2's term).
    ``"kl"``: for SimNorm latents (``simnorm_groups`` softmax groups), the KL divergence
    ``sum_g KL(z_g || z^_g)`` of each predicted group from the encoded one. Its gradient
    with respect to the prediction's logits is ``z^_g - z_g``, which stays whole where a
    group is confidently wrong; the squared error's passes through the softmax's Jacobian
    and fades there (a group at 0.9997 on the wrong entry moves ~750x slower).

    Examples:
        >>> z = simnorm(torch.tensor([[0.0, 5.0, 0.0, 0.0]]), 1)
        >>> float(consistency_error(z, z, 1, "kl"))
        0.0
        >>> round(float(consistency_error(torch.full((1, 2), 0.5), torch.tensor([[1.0, 0.0]]),
        ...                                1, "kl")), 4)  # log 2
        0.6931
    """
    check_consistency(kind, simnorm_groups)
    targets = targets.detach()
    if kind == "squared":
        return (predicted - targets).pow(2).sum(-1)
    tiny = torch.finfo(torch.float32).tiny  # a floor for log(0) only: softmax outputs are > 0
    predicted_g = predicted.float().unflatten(-1, (simnorm_groups, -1))
    target_g = targets.float().unflatten(-1, (simnorm_groups, -1))
    kl = torch.special.xlogy(target_g, target_g) - target_g * predicted_g.clamp_min(tiny).log()
    return kl.sum((-2, -1))


def masked_mean(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """The mean of ``values`` where ``mask`` is set, or weighted by a real-valued
    ``mask`` (importance weights); 0 where nothing is set."""
    total = mask.sum()
    return (values * mask).sum() / torch.where(total > 0, total, torch.ones_like(total))


class SimDistPretrainLoss(SimdistLoss):
    """Latent consistency + reward + value (+ BC) regression; no reconstruction.

    For every start ``t`` of a ``[B, T]`` slice: ``z_t = enc(o_{t-k+1..t})``, predicted
    ``z^_{t+i} = dyn(z^_{t+i-1}, a_{t+i-1})`` for ``i = 1..H``;

    - ``loss_consistency = mean_i ||z^_{t+i} - sg(enc(o_{t+i}))||^2`` (same encoder, no EMA),
      the squared error **summed** over latent dimensions: SimNorm latents are small per
      dimension (each group sums to 1), and a mean over 64 of them made this term ~0.005
      against BC ~1.6, too small to keep the latent predictive;
    - ``loss_reward = mean_i (r(z^_{t+i}, a_{t+i}) - r_{t+i})^2`` for ``i = 0..H-1``
      (``z^_t = z_t``) on recorded rewards, so rewards are right on predicted latents;
    - ``loss_value = mean_i (V(z^_{t+i}) - v_{t+i})^2`` for ``i = 0..H`` on the expert
      critic's labels (plain regression, no bootstrapping), up to ``z^_{t+H}``: the latent
      the planner's terminal value is read at;
    - ``loss_bc = mean_t ||pi(z_t) - a_t||^2`` on steps marked ``expert_active`` (the
      datasets mark the final expert's own, unperturbed actions).

    Targets after an episode start inside the horizon are masked out. Reference weights:
    latent 1, reward 1, value 1, action 4.

    ``extra_dynamics`` pretrains a *dynamics ensemble* on the shared encoder and heads:
    every dynamics module (the model's own first) rolls out from the same encoded
    latents, and the consistency, reward and value terms are the means over them (BC
    reads the encoder alone, once). The members differ by their initialisation; the
    encoder gets the mean of their gradients. Plan with them as one through
    :class:`~simdist.modules.WorldModelEnsemble` over
    :meth:`SimDistWorldModel.with_dynamics <simdist.modules.SimDistWorldModel.with_dynamics>` models.

    Examples:
        >>> wm = SimDistWorldModel.build(obs_dim=6, action_dim=2, size="tiny")
        >>> td = TensorDict({"observation": torch.randn(3, 8, 6), "action": torch.rand(3, 8, 2),
        ...     "is_init": torch.zeros(3, 8, 1, dtype=torch.bool), "value_target": torch.randn(3, 8, 1),
        ...     "expert_active": torch.ones(3, 8, 1, dtype=torch.bool),
        ...     "next": {"reward": torch.randn(3, 8, 1)}}, [3, 8])
        >>> out = SimDistPretrainLoss(wm, horizon=3)(td)
        >>> sorted(k for k in out.keys() if k.startswith("loss"))
        ['loss_bc', 'loss_consistency', 'loss_reward', 'loss_value']
    """

    @dataclass
    class _AcceptedKeys:
        observation: NestedKey = "observation"
        action: NestedKey = "action"
        reward: NestedKey = ("next", "reward")
        value_target: NestedKey = "value_target"
        expert_active: NestedKey = "expert_active"
        is_init: NestedKey = "is_init"

    default_keys = _AcceptedKeys

    def __init__(self, world_model: SimDistWorldModel, horizon: int = 5,
                 consistency_weight: float = 1.0, reward_weight: float = 1.0,
                 value_weight: float = 1.0, bc_weight: float = 4.0, check_inputs: bool = True,
                 extra_dynamics=()):
        super().__init__(check_inputs)
        if horizon < 1:
            raise ValueError(f"horizon must be >= 1, got {horizon}")
        self.world_model, self.horizon = world_model, horizon
        self.weights = dict(consistency=consistency_weight, reward=reward_weight,
                            value=value_weight, bc=bc_weight)
        self.extra_dynamics = nn.ModuleList(extra_dynamics)

    def trainable_parameters(self):
        return list(self.world_model.parameters()) + list(self.extra_dynamics.parameters())

    def forward(self, td: TensorDictBase) -> TensorDict:
        B, T = sequence_batch(td)
        H, wm = self.horizon, self.world_model
        is_init = self.read_flag(td, "is_init", (B, T))
        action = self.read(td, "action")
        latents = wm.encode_sequence(self.read(td, "observation"), is_init, action)
        S = T - H
        act = action.unfold(1, H, 1)[:, :S].transpose(-1, -2)
        reward_t = self.read_scalar(td, "reward", (B, T)).unfold(1, H, 1)[:, :S].transpose(-1, -2)
        value_t = self.read_scalar(td, "value_target", (B, T)).unfold(1, H + 1, 1)[:, :S].transpose(-1, -2)
        start_ok = complete_windows(is_init, wm.encoder.context)[:, :S, None].to(latents.dtype)
        members = [None, *self.extra_dynamics]  # None: the model's own dynamics
        rolled = [rollout_windows(wm, latents, action, is_init, H, d) for d in members]
        predicted = torch.cat([r[0] for r in rolled])                          # [K*B, S, H, L]
        targets, mask = rolled[0][1], torch.cat([r[2] for r in rolled])
        def tile(x):  # the same tensor for every member, stacked along the batch
            return x.repeat(len(members), *[1] * (x.dim() - 1))

        consistency = masked_mean((predicted - tile(targets.detach())).pow(2).sum(-1), mask)
        # z^_{t+i}, i = 0..H: the start latent then the predictions. Reward on i < H (each
        # with its action), value on every i: the planner reads the value at z^_{t+H}.
        path = torch.cat([tile(latents[:, :S, None]), predicted], 2)          # [K*B, S, H+1, L]
        path_mask = torch.cat([tile(start_ok), mask], -1)                      # [K*B, S, H+1]
        reward = masked_mean((wm.reward(path[:, :, :-1], tile(act)) - tile(reward_t))
                             .pow(2).squeeze(-1), path_mask[..., :-1])
        value = masked_mean((wm.value(path) - tile(value_t)).pow(2).squeeze(-1), path_mask)
        expert = self.read_flag(td, "expert_active", (B, T)).to(latents.dtype)
        expert = expert * complete_windows(is_init, wm.encoder.context).to(latents.dtype)
        bc = masked_mean((wm.policy(latents) - action).pow(2).mean(-1), expert)
        w = self.weights
        return self.finish(TensorDict({
            "loss_consistency": w["consistency"] * consistency,
            "loss_reward": w["reward"] * reward,
            "loss_value": w["value"] * value,
            "loss_bc": w["bc"] * bc,
            "latent_std": latents.std(0).mean().detach(),
        }, []))


class DynamicsFinetuneLoss(SimdistLoss):
    """SimDist finetuning on target data, training **only** the dynamics.

    ``loss_consistency`` is :class:`SimDistPretrainLoss`'s term (squared error summed over
    latent dimensions, averaged over starts and horizon steps), or with ``consistency="kl"``
    the KL divergence of each predicted SimNorm group from the encoded one
    (:func:`consistency_error`). Two optional terms make
    the dynamics right where the planner reads them, through the *frozen* heads:

    - ``loss_reward = reward_weight * mean_i (r(z^_{t+i}, a_{t+i}) - r_{t+i})^2`` for
      ``i = 1..H-1`` on the recorded target rewards (``i = 0`` has no predicted latent);
    - ``loss_value = value_weight * mean_i (V(z^_{t+i}) - sg V(z_{t+i}))^2`` for
      ``i = 1..H``: the frozen value head on the prediction against the same head on the
      encoded observation (target data carry no value labels; this asks the dynamics to
      land where the value head agrees, not to change what it says).

    The heads are evaluated with detached parameters and the encoder under
    ``torch.no_grad``, so encoder, reward, value and policy can never receive a gradient;
    :meth:`trainable_parameters` is the dynamics' parameters alone. With both weights 0
    (the default, the reference's loss) no head is evaluated with gradient; the frozen
    reward head's error on the predicted latents is reported either way
    (``reward_error_on_predictions``), and so is each slice's consistency error
    (``slice_error``, ``[B]``: the priority of
    :class:`~simdist.data.prioritised_slices.PrioritisedSlices`). A ``priority_weight``
    entry in the input (that sampler's importance weights) weighs each slice's windows in
    every term.

    Examples:
        >>> wm = SimDistWorldModel.build(obs_dim=6, action_dim=2, size="tiny")
        >>> loss = DynamicsFinetuneLoss(wm, horizon=3, reward_weight=1.0)
        >>> {id(p) for p in loss.trainable_parameters()} == {id(p) for p in wm.dynamics.parameters()}
        True
        >>> td = TensorDict({"observation": torch.randn(2, 8, 6), "action": torch.rand(2, 8, 2),
        ...     "is_init": torch.zeros(2, 8, 1, dtype=torch.bool),
        ...     "next": {"reward": torch.randn(2, 8, 1)}}, [2, 8])
        >>> sorted(k for k in loss(td).keys() if k.startswith("loss"))
        ['loss_consistency', 'loss_reward']
    """

    @dataclass
    class _AcceptedKeys:
        observation: NestedKey = "observation"
        action: NestedKey = "action"
        reward: NestedKey = ("next", "reward")
        is_init: NestedKey = "is_init"
        priority_weight: NestedKey = "priority_weight"

    default_keys = _AcceptedKeys

    def __init__(self, world_model: SimDistWorldModel, horizon: int = 5,
                 reward_weight: float = 0.0, value_weight: float = 0.0,
                 consistency: str = "squared", check_inputs: bool = True):
        super().__init__(check_inputs)
        # the latent's SimNorm groups are the encoder's (its outputs are the targets); read
        # with a default because encoder and dynamics are swappable parts
        self.simnorm_groups = getattr(world_model.encoder, "simnorm_groups", None)
        check_consistency(consistency, self.simnorm_groups)
        self.consistency = consistency
        if horizon < 1:
            raise ValueError(f"horizon must be >= 1, got {horizon}")
        for name, w in (("reward_weight", reward_weight), ("value_weight", value_weight)):
            if not (w >= 0 and math.isfinite(w)):
                raise ValueError(f"{name} must be a finite number >= 0, got {w}")
        if reward_weight > 0 and horizon < 2:
            raise ValueError("reward_weight > 0 needs horizon >= 2: the reward term reads "
                             "predicted latents z^_{t+1..t+H-1}")
        self.world_model, self.horizon = world_model, horizon
        self.reward_weight, self.value_weight = reward_weight, value_weight

    def trainable_parameters(self):
        return list(self.world_model.dynamics.parameters())

    def forward(self, td: TensorDictBase) -> TensorDict:
        return self._loss(td, whole_model=False)

    def consistency_all_parts(self, td: TensorDictBase) -> TensorDict:
        """The same terms with gradients into the encoder and heads too (an ablation:
        "finetune the whole world model"; consistency and value targets stay
        stop-gradient)."""
        return self._loss(td, whole_model=True)

    def _loss(self, td: TensorDictBase, whole_model: bool) -> TensorDict:
        B, T = sequence_batch(td)
        wm, H = self.world_model, self.horizon
        is_init = self.read_flag(td, "is_init", (B, T))
        action = self.read(td, "action")
        with torch.set_grad_enabled(whole_model):  # frozen: the encoder builds no graph
            latents = wm.encode_sequence(self.read(td, "observation"), is_init, action)
        predicted, targets, mask = rollout_windows(wm, latents, action, is_init, H)
        error = consistency_error(predicted, targets, self.simnorm_groups,
                                  self.consistency)                             # [B, S, H]
        with torch.no_grad():
            slice_error = (error * mask).sum((1, 2)) / mask.sum((1, 2)).clamp_min(1.0)
        if self.tensor_keys.priority_weight in td.keys(include_nested=True):
            # Prioritised slices: each slice's windows count by its importance weight
            # (self-normalised, so the loss keeps its scale).
            weight = self.read(td, "priority_weight")
            if weight.shape not in ((B, T), (B, T, 1)):
                raise ValueError(f"priority_weight must be [B, T] or [B, T, 1] (one weight "
                                 f"per slice, repeated on its steps), got {tuple(weight.shape)}")
            weight = weight.reshape(B, T)[:, 0]
            if not (torch.isfinite(weight).all() and (weight >= 0).all()):
                raise ValueError("priority_weight must be finite and >= 0")
            mask = mask * weight.to(mask.dtype)[:, None, None]
        out = {"loss_consistency": masked_mean(error, mask),
               "slice_error": slice_error}
        S = T - H
        act = action.unfold(1, H, 1)[:, :S].transpose(-1, -2)[:, :, 1:]
        reward_t = self.read_scalar(td, "reward", (B, T)).unfold(1, H, 1)[:, :S].transpose(-1, -2)[:, :, 1:]
        reward_head = wm.reward_head if whole_model else frozen(wm.reward_head)
        value_head = wm.value_head if whole_model else frozen(wm.value_head)
        if self.reward_weight > 0:
            out["loss_reward"] = self.reward_weight * masked_mean(
                (reward_head(predicted[:, :, :-1], act) - reward_t).pow(2).squeeze(-1),
                mask[..., :-1])
        if self.value_weight > 0:
            out["loss_value"] = self.value_weight * masked_mean(
                (value_head(predicted) - value_head(targets).detach()).pow(2).squeeze(-1), mask)
        with torch.no_grad():
            out["reward_error_on_predictions"] = masked_mean(
                (wm.reward(predicted[:, :, :-1], act) - reward_t).pow(2).squeeze(-1),
                mask[..., :-1]) if H > 1 else torch.zeros(())
        return self.finish(TensorDict(out, []))


def frozen(module: torch.nn.Module):
    """``module`` called with detached parameters: gradients reach its inputs, never it.

    Examples:
        >>> head = torch.nn.Linear(2, 1)
        >>> x = torch.ones(1, 2, requires_grad=True)
        >>> frozen(head)(x).sum().backward()
        >>> head.weight.grad is None, x.grad is not None
        (True, True)
    """
    params = {name: p.detach() for name, p in module.named_parameters()}
    return lambda *args: torch.func.functional_call(module, params, args)


@torch.no_grad()
def latent_prediction_error(world_model: SimDistWorldModel, td: TensorDictBase,
                            horizon: int) -> list[float]:
    """Open-loop prediction error of the latent dynamics, relative to the latent's spread.

    For ``i = 1..horizon``: the mean over starts of ``||z^_{t+i} - enc(o_{t+i})||^2``
    divided by the total variance of the encoder's latents on the same data. 0 is a
    perfect model; 1 is no better than predicting the mean latent (a model that is not
    predictive). Reads ``observation``, ``action`` and ``is_init`` of ``[B, T]`` episodes.

    Examples:
        >>> wm = SimDistWorldModel.build(obs_dim=4, action_dim=2, size="tiny")
        >>> td = TensorDict({"observation": torch.randn(2, 9, 4), "action": torch.rand(2, 9, 2),
        ...                  "is_init": torch.zeros(2, 9, 1, dtype=torch.bool)}, [2, 9])
        >>> len(latent_prediction_error(wm, td, horizon=3))
        3
    """
    B, T = sequence_batch(td)
    is_init = td.get("is_init").reshape(B, T).bool()
    latents = world_model.encode_sequence(td.get("observation"), is_init, td.get("action"))
    predicted, targets, mask = rollout_windows(world_model, latents, td.get("action"), is_init,
                                               horizon)
    error = (predicted - targets).pow(2).sum(-1)                     # [B, S, H]
    per_step = (error * mask).sum((0, 1)) / mask.sum((0, 1)).clamp_min(1.0)
    spread = latents.reshape(-1, latents.shape[-1]).var(0).sum().clamp_min(1e-12)
    return (per_step / spread).tolist()


@torch.no_grad()
def latent_prediction_skill(world_model: SimDistWorldModel, td: TensorDictBase, horizon: int,
                            seed: int = 0) -> dict[str, list[float]]:
    """:func:`latent_prediction_error` beside two references that say what it is worth.

    A relative error of .16 sounds small, but the latent of a 50 Hz robot can move by
    that much in one step. Per predicted step ``i = 1..horizon``, each relative to the
    latent's total variance like :func:`latent_prediction_error`:

    - ``"model"``: the dynamics rolled out with the recorded actions (that function's value);
    - ``"copy"``: predicting no change, ``z^_{t+i} = z_t`` (a residual dynamics' start);
    - ``"shuffled"``: the dynamics rolled out with another window's recorded actions (the
      windows permuted with ``seed``), i.e. what the model predicts from wrong actions.

    ``1 - model / copy`` is the share of the latent's change the model explains, and
    ``(shuffled - model) / (copy - model)`` the part of that gain that comes from reading
    the actions: a planner ranks candidate actions only through it.

    Examples:
        >>> wm = SimDistWorldModel.build(obs_dim=4, action_dim=2, size="tiny")
        >>> td = TensorDict({"observation": torch.randn(2, 9, 4), "action": torch.rand(2, 9, 2),
        ...                  "is_init": torch.zeros(2, 9, 1, dtype=torch.bool)}, [2, 9])
        >>> sorted(latent_prediction_skill(wm, td, horizon=3))
        ['copy', 'model', 'shuffled']
    """
    B, T = sequence_batch(td)
    is_init = td.get("is_init").reshape(B, T).bool()
    latents = world_model.encode_sequence(td.get("observation"), is_init, td.get("action"))
    actions = td.get("action")
    predicted, targets, mask = rollout_windows(world_model, latents, actions, is_init, horizon)
    S = predicted.shape[1]
    windows = actions.unfold(1, horizon, 1)[:, :S].transpose(-1, -2)        # [B, S, H, A]
    flat = windows.reshape(B * S, horizon, -1)
    order = torch.randperm(B * S, generator=torch.Generator().manual_seed(seed))
    shuffled = world_model.rollout(latents[:, :S], flat[order.to(flat.device)].reshape(windows.shape))
    spread = latents.reshape(-1, latents.shape[-1]).var(0).sum().clamp_min(1e-12)
    weight = mask.sum((0, 1)).clamp_min(1.0)

    def relative(prediction: torch.Tensor) -> list[float]:
        error = (prediction - targets).pow(2).sum(-1)                      # [B, S, H]
        return ((error * mask).sum((0, 1)) / weight / spread).tolist()

    return {"model": relative(predicted), "copy": relative(latents[:, :S, None].expand_as(targets)),
            "shuffled": relative(shuffled)}
