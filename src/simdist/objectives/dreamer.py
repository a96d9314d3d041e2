"""Dreamer objectives for the TWIST teacher: world model (ELBO) and actor-critic in imagination.

Why not TorchRL's ``DreamerModelLoss`` / ``DreamerActorLoss`` / ``DreamerValueLoss``: they
expect Gaussian latents (``prior_mean``/``prior_std`` keys) and imagine through a
``DreamerEnv`` rollout, one TensorDict per step; our RSSM has categorical latents and
imagines with tensors. We reuse TorchRL's TD(lambda) estimator and ``hold_out_net``.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey
from torchrl.objectives.utils import hold_out_net
from torchrl.objectives.value.functional import td_lambda_return_estimate

from simdist.modules.encoders import PixelEncoder
from simdist.modules.heads import PixelDecoder, pixels_to_target
from simdist.modules.rssm import RSSMState
from simdist.modules.world_model import DreamerWorldModel
from simdist.objectives.common import SimdistLoss, sequence_batch
from simdist.objectives.return_scale import ReturnScale
from simdist.objectives.target_standardiser import TargetStandardiser

# how the actor's objective reaches its parameters (DreamerActorCriticLoss.actor_gradient)
ACTOR_GRADIENTS = ("dynamics", "reinforce")


def balanced_kl(rssm, post_logits, prior_logits, balance: float, free_nats: float):
    """DreamerV2 KL balancing with per-step free nats.

    ``balance * max(KL[sg(q) || p], free) + (1 - balance) * max(KL[q || sg(p)], free)``:
    the prior moves towards the posterior faster than the posterior towards the prior.
    """
    to_prior = rssm.kl(post_logits.detach(), prior_logits).clamp_min(free_nats)
    to_post = rssm.kl(post_logits, prior_logits.detach()).clamp_min(free_nats)
    return balance * to_prior + (1 - balance) * to_post


class DreamerWorldModelLoss(SimdistLoss):
    """``-ln p(x|h,z) - ln p(r|h,z) + beta * KL[q(z|h,x) || p(z|h)]`` (TWIST Sec. III-B).

    Reconstruction and reward are unit-variance Gaussians (squared error / 2, summed over
    the observation's dimensions); KL uses DreamerV2 balancing and free nats. Posterior
    states are written back into the input TensorDict (detached) under
    ``("posterior", "belief")`` / ``("posterior", "stoch")`` for the actor-critic loss.

    The decoder reconstructs the observation, or with ``set_keys(reconstruction=key)``
    another vector of the same steps (TWIST's "Dreamer State Recon." baseline: images in,
    the privileged state out). With a ``reconstruction_standardiser``
    (:class:`TargetStandardiser`) a vector target is standardised per dimension by its
    running statistics, so each dimension weighs the same in the loss and the decoder
    predicts in standardised units.

    Examples:
        >>> wm = DreamerWorldModel.teacher(state_dim=3, action_dim=1, size="tiny")
        >>> td = TensorDict({"action": torch.zeros(2, 4, 1),
        ...                  "is_init": torch.zeros(2, 4, 1, dtype=torch.bool),
        ...                  "next": {"state": torch.zeros(2, 4, 3), "reward": torch.zeros(2, 4, 1)}},
        ...                 [2, 4])
        >>> sorted(k for k in DreamerWorldModelLoss(wm)(td).keys() if k.startswith("loss"))
        ['loss_kl', 'loss_reconstruction', 'loss_reward']
    """

    @dataclass
    class _AcceptedKeys:
        observation: NestedKey = ("next", "state")
        action: NestedKey = "action"
        reward: NestedKey = ("next", "reward")
        terminated: NestedKey = ("next", "terminated")
        is_init: NestedKey = "is_init"
        reconstruction: NestedKey | None = None  # None: the observation

    default_keys = _AcceptedKeys

    def __init__(self, world_model: DreamerWorldModel, kl_scale: float = 1.0,
                 kl_balance: float = 0.8, free_nats: float = 1.0, reward_scale: float = 1.0,
                 reconstruction_scale: float = 1.0, continue_scale: float = 1.0,
                 reconstruction_standardiser: TargetStandardiser | None = None,
                 check_inputs: bool = True):
        super().__init__(check_inputs)
        if world_model.decoder is None or world_model.reward_head is None:
            raise ValueError("DreamerWorldModelLoss needs a world model with decoder and "
                             "reward head (e.g. DreamerWorldModel.teacher(...))")
        self.reconstruction_standardiser = reconstruction_standardiser
        self.world_model = world_model
        self.kl_scale, self.kl_balance, self.free_nats = kl_scale, kl_balance, free_nats
        self.reward_scale, self.reconstruction_scale = reward_scale, reconstruction_scale
        self.continue_scale = continue_scale

    def trainable_parameters(self):
        return list(self.world_model.parameters())

    def forward(self, td: TensorDictBase) -> TensorDict:
        B, T = sequence_batch(td)
        # Images must follow the encoder's convention (uint8, or floats in [-0.5, 0.5]).
        obs = (self.read_pixels(td, "observation")
               if isinstance(self.world_model.encoder, PixelEncoder)
               else self.read(td, "observation"))
        out = self.world_model.observe(obs, self.read(td, "action"),
                                       self.read_flag(td, "is_init", (B, T)))
        features = DreamerWorldModel.features(out)
        prediction = self.world_model.decode(features)
        if self.tensor_keys.reconstruction is not None:
            obs = self.read(td, "reconstruction")
        target = pixels_to_target(obs) if obs.dtype == torch.uint8 else obs
        if self.reconstruction_standardiser is not None:
            if isinstance(self.world_model.decoder, PixelDecoder):
                raise ValueError(f"{type(self).__name__}: reconstruction_standardiser "
                                 "standardises a vector target, but the decoder "
                                 "reconstructs images")
            target = self.reconstruction_standardiser(target)
        if prediction.shape != target.shape:
            raise ValueError(f"{type(self).__name__}: the decoder predicts "
                             f"{tuple(prediction.shape)} but the reconstruction target is "
                             f"{tuple(target.shape)}")
        event_dims = tuple(range(2, target.dim()))
        recon = 0.5 * (prediction - target).pow(2).sum(event_dims).mean()
        reward_t = self.read_scalar(td, "reward", (B, T))
        reward = 0.5 * (self.world_model.reward(features) - reward_t).pow(2).mean()
        rssm = self.world_model.rssm
        kl = balanced_kl(rssm, out["posterior_logits"], out["prior_logits"], self.kl_balance,
                         self.free_nats).mean()
        losses = {"loss_reconstruction": self.reconstruction_scale * recon,
                  "loss_reward": self.reward_scale * reward,
                  "loss_kl": self.kl_scale * kl}
        if self.world_model.continue_head is not None:
            cont = 1.0 - self.read(td, "terminated").float()
            logit = self.world_model.continue_head(features)
            losses["loss_continue"] = self.continue_scale * torch.nn.functional.\
                binary_cross_entropy_with_logits(logit, cont.reshape(logit.shape))
        td.set(("posterior", "belief"), out["belief"].detach())
        td.set(("posterior", "stoch"), out["stoch"].detach())
        diag = {"kl": rssm.kl(out["posterior_logits"], out["prior_logits"]).mean().detach()}
        return self.finish(TensorDict({**losses, **diag}, []))


class DreamerActorCriticLoss(SimdistLoss):
    """Actor and critic trained in imagination from posterior states (DreamerV2).

    From every posterior state of the batch the actor imagines ``horizon`` steps through
    the frozen world model; lambda-returns (TorchRL's ``td_lambda_return_estimate``) of
    predicted rewards bootstrapped with a slow target critic give the actor's objective
    (dynamics backpropagation, plus an entropy bonus) and the critic's regression target.
    The world model is held out: it receives no gradient.

    Args:
        world_model: a model with a reward head (the teacher).
        actor: :class:`~simdist.modules.Actor`.
        critic: value head on model features.
        horizon: imagination length.
        gamma: discount.
        lmbda: the lambda of the lambda-returns.
        entropy_coeff: weight of the actor's entropy bonus.
        target_tau: Polyak rate of :meth:`update_target`.
        max_starts: imagine from at most this many posterior states, drawn at random
            (``None``: all of them, as DreamerV2); cuts the cost on CPU.
        actor_input_noise: the actor reads each imagined latent with fresh Gaussian noise
            of this many standard deviations per feature (the starts' batch std), and the
            rollout follows the actions it takes: a policy trained to act well when its
            reading of the latent is off, e.g. by a student's perception (0: DreamerV2).
        return_scale: a :class:`ReturnScale` that the actor's returns are divided by
            (DreamerV3's return normalisation; ``None``: unscaled, DreamerV2). The critic
            still regresses the unscaled returns.
        actor_gradient: ``"dynamics"``, the returns' gradient backpropagated through the
            world model into the actions (DreamerV1/V2 on continuous control), or
            ``"reinforce"``, the score-function gradient ``log pi(a|z) * sg(R - V(z))``
            with the critic as baseline and the imagination run without gradient
            (DreamerV3's estimator): the actor cannot follow a wrong model's gradient
            into actions the model mispredicts, it learns only from which of its own
            samples the model scores higher. The entropy bonus is reparameterised in
            both cases.

    Examples:
        >>> from simdist.modules import Actor, ScalarHead
        >>> wm = DreamerWorldModel.teacher(state_dim=3, action_dim=1, size="tiny")
        >>> f = wm.rssm.feature_dim
        >>> loss = DreamerActorCriticLoss(wm, Actor(f, 1, hidden=8), ScalarHead(f, 8), horizon=3)
        >>> start = wm.rssm.initial((2, 4))  # normally DreamerWorldModelLoss's posteriors
        >>> td = TensorDict({"posterior": {"belief": start.belief, "stoch": start.stoch}}, [2, 4])
        >>> sorted(loss(td).keys())
        ['entropy', 'imagined_reward', 'lambda_return', 'loss_actor', 'loss_critic']

        With DreamerV3's return normalisation the output also reports the divisor:

        >>> from simdist.objectives.return_scale import ReturnScale
        >>> loss = DreamerActorCriticLoss(wm, Actor(f, 1, hidden=8), ScalarHead(f, 8), horizon=3,
        ...                               return_scale=ReturnScale())
        >>> "return_scale" in loss(td).keys()
        True
    """

    @dataclass
    class _AcceptedKeys:
        belief: NestedKey = ("posterior", "belief")
        stoch: NestedKey = ("posterior", "stoch")

    default_keys = _AcceptedKeys

    def __init__(self, world_model: DreamerWorldModel, actor, critic, horizon: int = 15,
                 gamma: float = 0.99, lmbda: float = 0.95, entropy_coeff: float = 3e-4,
                 target_tau: float = 0.02, max_starts: int | None = None,
                 actor_input_noise: float = 0.0, return_scale: ReturnScale | None = None,
                 actor_gradient: str = "dynamics", check_inputs: bool = True):
        super().__init__(check_inputs)
        if actor_gradient not in ACTOR_GRADIENTS:
            raise ValueError(f"unknown actor_gradient {actor_gradient!r}; "
                             f"valid: {list(ACTOR_GRADIENTS)}")
        self.actor_gradient = actor_gradient
        self.return_scale = return_scale
        if not actor_input_noise >= 0:
            raise ValueError(f"actor_input_noise must be >= 0, got {actor_input_noise}")
        self.actor_input_noise = float(actor_input_noise)
        if horizon < 1:
            raise ValueError(f"horizon must be >= 1, got {horizon}")
        if max_starts is not None and max_starts < 1:
            raise ValueError(f"max_starts must be >= 1 or None, got {max_starts}")
        self.max_starts = max_starts
        self.world_model, self.actor, self.critic = world_model, actor, critic
        self.target_critic = copy.deepcopy(critic).requires_grad_(False)
        self.horizon, self.gamma, self.lmbda = horizon, gamma, lmbda
        self.entropy_coeff, self.target_tau = entropy_coeff, target_tau

    def trainable_parameters(self):
        return list(self.actor.parameters()) + list(self.critic.parameters())

    @torch.no_grad()
    def update_target(self) -> None:
        """Polyak-averages the critic into the target critic."""
        for target, source in zip(self.target_critic.parameters(), self.critic.parameters()):
            target.lerp_(source, self.target_tau)

    def forward(self, td: TensorDictBase) -> TensorDict:
        belief, stoch = self.read(td, "belief"), self.read(td, "stoch")
        state = RSSMState(belief.detach().flatten(0, -2), stoch.detach().flatten(0, -2))
        if self.max_starts and state.belief.shape[0] > self.max_starts:
            index = torch.randperm(state.belief.shape[0], device=belief.device)[:self.max_starts]
            state = RSSMState(state.belief[index], state.stoch[index])
        rssm = self.world_model.rssm
        reinforce = self.actor_gradient == "reinforce"
        features, reads, actions, log_probs = [state.features()], [], [], []
        # per-feature scale of the reading noise, from the starts (no gradient)
        noise_scale = self.actor_input_noise * features[0].std(0, keepdim=True) \
            if self.actor_input_noise and features[0].shape[0] > 1 else None
        # REINFORCE needs no gradient through the imagination: the rollout is data
        with hold_out_net(self.world_model), torch.set_grad_enabled(
                torch.is_grad_enabled() and not reinforce):
            for _ in range(self.horizon):
                read = features[-1] if noise_scale is None else \
                    features[-1] + noise_scale * torch.randn_like(features[-1])
                dist = self.actor.distribution(read)
                action = dist.rsample()
                if reinforce:  # re-read with gradient after the rollout
                    reads.append(read)
                    actions.append(action)
                else:
                    log_probs.append(dist.log_prob(action))
                belief_, logits = rssm.prior_step(state, action)
                state = RSSMState(belief_, rssm.sample(logits))
                features.append(state.features())
            feats = torch.stack(features, 1)                       # [N, H+1, F]
            reward = self.world_model.reward(feats[:, 1:])          # [N, H, 1]
            next_value = self.target_critic(feats[:, 1:])           # [N, H, 1]
        done = torch.zeros_like(reward, dtype=torch.bool)
        returns = td_lambda_return_estimate(self.gamma, self.lmbda, next_value, reward, done)
        diag = {}
        scale = None
        if self.return_scale is not None:
            scale = self.return_scale.update(returns.detach())
            diag["return_scale"] = scale.clone()
        value = self.critic(feats[:, :-1].detach())
        if reinforce:
            # the actor re-reads the (detached) rollout: score function of the actions
            # it took, and a reparameterised sample for the entropy
            dist = self.actor.distribution(torch.stack(reads, 1))
            log_prob = dist.log_prob(torch.stack(actions, 1)).reshape(returns.shape)
            entropy = -dist.log_prob(dist.rsample()).mean()
            advantage = (returns - value).detach()
            if scale is not None:
                advantage = advantage / scale
            loss_actor = -(log_prob * advantage).mean() - self.entropy_coeff * entropy
            diag["advantage"] = advantage.abs().mean()
        else:
            entropy = -torch.stack(log_probs, 1).mean()
            objective = returns if scale is None else returns / scale
            # a constant divisor: the gradient of the returns shrinks, the entropy's does not
            loss_actor = -objective.mean() - self.entropy_coeff * entropy
        loss_critic = 0.5 * (value - returns.detach()).pow(2).mean()
        return self.finish(TensorDict({
            "loss_actor": loss_actor, "loss_critic": loss_critic,
            "imagined_reward": reward.mean().detach(), "entropy": entropy.detach(),
            "lambda_return": returns.mean().detach(), **diag}, []))
