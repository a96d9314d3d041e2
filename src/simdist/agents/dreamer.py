"""A Dreamer agent (world model + actor-critic in imagination): the TWIST teacher.

The agent owns its optimisers and loops; the losses own the math. Acting is recurrent:
the filtering state ``(belief, stoch, previous action)`` rides in the TensorDict under
``("agent", ...)`` keys (created and reset by :meth:`DreamerAgent.make_primer`, with
``InitTracker`` marking episode starts), so the policy works inside TorchRL rollouts,
``ParallelEnv`` and collectors like any recurrent TorchRL policy.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.data import Composite, Unbounded
from torchrl.envs import TensorDictPrimer

from simdist.agents import checkpoint as ckpt_format
from simdist.agents.action_spec import action_bounds
from simdist.agents.describe import build_dreamer_model, describe_dreamer_model
from simdist.modules import Actor, DreamerWorldModel, ScalarHead
from simdist.modules.heads import StateDecoder
from simdist.modules.encoders import PixelEncoder
from simdist.modules.checks import check_finite
from simdist.objectives.common import check_pixels
from simdist.modules.rssm import RSSMState
from simdist.objectives import DreamerActorCriticLoss, DreamerWorldModelLoss, ReturnScale
from simdist.objectives.dreamer import ACTOR_GRADIENTS
from simdist.objectives.target_standardiser import TargetStandardiser
from simdist.utils.device import module_device, move_to_device


@dataclass
class DreamerConfig:
    """Dreamer hyperparameters (DreamerV2 defaults where they apply).

    Examples:
        >>> config = DreamerConfig(size="tiny", horizon=5, exploration_noise=0.1)
        >>> agent = DreamerAgent.for_state(state_dim=5, action_dim=1, config=config)
        >>> agent.behaviour_loss.horizon, agent.policy().noise, agent.policy(explore=False).noise
        (5, 0.1, 0.0)
    """

    size: str = "small"
    horizon: int = 15
    model_lr: float = 3e-4
    actor_lr: float = 8e-5
    critic_lr: float = 8e-5
    grad_clip: float = 100.0
    exploration_noise: float = 0.3
    entropy_coeff: float = 3e-4
    imagination_starts: int | None = None  # None: every posterior state (DreamerV2)
    # the actor reads imagined latents with this many feature stds of fresh noise
    # (DreamerActorCriticLoss.actor_input_noise; 0: DreamerV2)
    actor_input_noise: float = 0.0
    # the actor's distribution (Actor.distribution): "tanh_normal" (unbounded pre-tanh
    # mean; every teacher so far) or "trunc_normal" (DreamerV2's)
    actor_distribution: str = "tanh_normal"
    # how the policy explores: "noise", its mode plus exploration_noise (DreamerV1), or
    # "sample", a draw from the actor's distribution (DreamerV2; exploration_noise unused)
    exploration: str = "noise"
    # the actor's returns: "none", as they come (DreamerV2), or "percentile", divided by
    # their running 95th-5th percentile range when above 1 (DreamerV3; ReturnScale)
    return_normalisation: str = "none"
    # how the actor's objective reaches it: "dynamics", backpropagated through the world
    # model (DreamerV1/V2), or "reinforce", score function with the critic as baseline
    # (DreamerV3; DreamerActorCriticLoss.actor_gradient)
    actor_gradient: str = "dynamics"
    # weight of the reward term in the world model's loss (DreamerWorldModelLoss.
    # reward_scale; 1: DreamerV2). The image term sums over 64x64x3 values, so at 1 the
    # reward is a small share of what shapes the latent
    reward_scale: float = 1.0
    # how a pixel Dreamer reads its image (PixelEncoder.arch): "dreamer", the CNN, or
    # "keypoints", spatial-softmax keypoints (where things are: a thin pole's lean);
    # state Dreamers have no image encoder and ignore it
    encoder: str = "dreamer"
    # standardise a vector reconstruction target per dimension by its running mean and
    # std (TargetStandardiser) so each dimension weighs the same; unused by image
    # decoders. Dreamer State Recon.'s raw cartpole state puts ~90% of the loss on the
    # pole's angular velocity and ~2% on its lean (docs/findings.md, "A standardised
    # state target for Dreamer State Recon.")
    standardise_reconstruction: bool = False

    def __post_init__(self):
        if self.actor_distribution not in Actor.DISTRIBUTIONS:
            raise ValueError(f"DreamerConfig: unknown actor_distribution "
                             f"{self.actor_distribution!r}; valid: {list(Actor.DISTRIBUTIONS)}")
        if self.exploration not in EXPLORATIONS:
            raise ValueError(f"DreamerConfig: unknown exploration {self.exploration!r}; "
                             f"valid: {list(EXPLORATIONS)}")
        if self.return_normalisation not in RETURN_NORMALISATIONS:
            raise ValueError(f"DreamerConfig: unknown return_normalisation "
                             f"{self.return_normalisation!r}; "
                             f"valid: {list(RETURN_NORMALISATIONS)}")
        if not self.reward_scale > 0:
            raise ValueError(f"DreamerConfig: reward_scale must be > 0, got {self.reward_scale}")
        if self.encoder not in PixelEncoder.ARCHS:
            raise ValueError(f"DreamerConfig: unknown encoder {self.encoder!r}; "
                             f"valid: {list(PixelEncoder.ARCHS)}")
        if self.actor_gradient not in ACTOR_GRADIENTS:
            raise ValueError(f"DreamerConfig: unknown actor_gradient {self.actor_gradient!r}; "
                             f"valid: {list(ACTOR_GRADIENTS)}")


EXPLORATIONS = ("noise", "sample")
RETURN_NORMALISATIONS = ("none", "percentile")


class DreamerPolicy(TensorDictModuleBase):
    """Filters observations with a world model's RSSM and acts with an actor on its latent.

    Args:
        world_model: supplies ``encoder`` and ``rssm``.
        actor: maps RSSM features to actions in [-1, 1].
        obs_key: observation read each step (``"state"``, or ``"pixels"`` for a student).
        obs_event_dims: trailing dimensions of one observation (1 for vectors, 3 for HWC).
        exploration_noise: std of Gaussian action noise when ``explore``.
        explore: explore (collection) or act with the actor's mode (evaluation).
        sample: explore by drawing from ``actor.distribution`` instead of adding noise.

    Examples:
        >>> agent = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
        >>> policy = DreamerPolicy(agent.world_model, agent.actor, obs_key="state", explore=False)
        >>> td = policy(TensorDict({"state": torch.zeros(2, 5),
        ...                         "is_init": torch.ones(2, 1, dtype=torch.bool)}, [2]))
        >>> td["action"].shape, td["next", "agent", "belief"].shape
        (torch.Size([2, 1]), torch.Size([2, 32]))
    """

    def __init__(self, world_model: DreamerWorldModel, actor, obs_key="state",
                 obs_event_dims: int = 1, exploration_noise: float = 0.0, explore: bool = True,
                 sample: bool = False):
        super().__init__()
        self.world_model, self.actor = world_model, actor
        self.obs_key, self.obs_event_dims = obs_key, obs_event_dims
        self.sample = sample and explore
        self.noise = exploration_noise if explore and not sample else 0.0
        keys = [("agent", k) for k in ("belief", "stoch", "prev_action")]
        self.in_keys = [obs_key, "is_init", *keys]
        self.out_keys = ["action", *[("next", *k) for k in keys]]

    @torch.no_grad()
    def forward(self, td: TensorDictBase) -> TensorDictBase:
        rssm = self.world_model.rssm
        obs = td.get(self.obs_key)
        check_finite(self.obs_key, obs)  # a NaN would become a NaN action, silently
        if self.obs_event_dims == 3:  # images: uint8, or floats already in [-0.5, 0.5]
            check_pixels(type(self).__name__, self.obs_key, obs)
        # Inputs go to the model's device and outputs come back to the env's, so a model
        # on a GPU acts in a CPU env (the recurrent state rides in the env's TensorDict).
        home, device = obs.device, module_device(self.world_model)
        obs = obs.to(device)
        batch = obs.shape[: obs.dim() - self.obs_event_dims]
        is_init = td.get("is_init", None)
        if is_init is None:
            raise KeyError("DreamerPolicy needs 'is_init': add torchrl.envs.InitTracker()")
        keep = (~is_init.to(device).reshape(*batch, 1).bool()).float()

        def get(key, size):
            value = td.get(("agent", key), None)
            if value is None:
                return torch.zeros(*batch, size, device=device)
            return value.to(device).reshape(*batch, size)

        state = RSSMState(get("belief", rssm.deter_dim), get("stoch", rssm.stoch_dim))
        embed = self.world_model.encoder(obs)
        state = rssm.filter_step(state, get("prev_action", rssm.action_dim), embed, keep)
        features = state.features()
        action = (self.actor.distribution(features).sample() if self.sample
                  else self.actor(features))
        if self.noise:
            action = (action + self.noise * torch.randn_like(action)).clamp(-1, 1)
        action = action.to(home)
        td.set("action", action)
        td.set(("next", "agent", "belief"), state.belief.to(home))
        td.set(("next", "agent", "stoch"), state.stoch.to(home))
        td.set(("next", "agent", "prev_action"), action)
        return td


class DreamerAgent(ckpt_format.LoadableAgent):
    """World model, actor and critic with their losses and optimisers.

    Examples:
        >>> agent = DreamerAgent.for_state(state_dim=5, action_dim=1, config=DreamerConfig(size="tiny"))
        >>> td = TensorDict({"action": torch.zeros(2, 6, 1),
        ...     "is_init": torch.zeros(2, 6, 1, dtype=torch.bool),
        ...     "next": {"state": torch.zeros(2, 6, 5), "reward": torch.zeros(2, 6, 1)}}, [2, 6])
        >>> sorted(k for k in agent.update(td) if k.startswith("loss"))
        ['loss_actor', 'loss_critic', 'loss_kl', 'loss_reconstruction', 'loss_reward']
    """

    def __init__(self, world_model: DreamerWorldModel, action_dim: int, config: DreamerConfig,
                 obs_key="state", reconstruct_key: str | None = None):
        self.world_model, self.config = world_model, config
        feature_dim, hidden = world_model.rssm.feature_dim, world_model.rssm.input_net[0].out_features
        self.actor = Actor(feature_dim, action_dim, hidden=hidden, layers=3,
                           distribution=config.actor_distribution)
        self.critic = ScalarHead(feature_dim, hidden)
        standardiser = None
        if config.standardise_reconstruction and isinstance(world_model.decoder, StateDecoder):
            standardiser = TargetStandardiser(world_model.decoder.state_dim)
        self.model_loss = DreamerWorldModelLoss(world_model, reward_scale=config.reward_scale,
                                                reconstruction_standardiser=standardiser)
        self.model_loss.set_keys(observation=("next", obs_key))
        self.reconstruct_key = reconstruct_key  # None: the decoder reconstructs obs_key
        if reconstruct_key is not None:
            self.model_loss.set_keys(reconstruction=("next", reconstruct_key))
        self.behaviour_loss = DreamerActorCriticLoss(
            world_model, self.actor, self.critic, horizon=config.horizon,
            entropy_coeff=config.entropy_coeff, max_starts=config.imagination_starts,
            actor_input_noise=config.actor_input_noise,
            return_scale=ReturnScale() if config.return_normalisation == "percentile" else None,
            actor_gradient=config.actor_gradient)
        self.model_optim = torch.optim.Adam(world_model.parameters(), lr=config.model_lr)
        self.actor_optim = torch.optim.Adam(self.actor.parameters(), lr=config.actor_lr)
        self.critic_optim = torch.optim.Adam(self.critic.parameters(), lr=config.critic_lr)
        self.obs_key = obs_key
        self.obs_event_dims = 3 if obs_key == "pixels" else 1  # HWC images or vectors

    @classmethod
    def for_state(cls, state_dim: int, action_dim: int, config: DreamerConfig = DreamerConfig()):
        """The TWIST teacher (and the Oracle): Dreamer on privileged ``"state"``."""
        return cls(DreamerWorldModel.teacher(state_dim, action_dim, config.size), action_dim,
                   config)

    @classmethod
    def for_pixels(cls, action_dim: int, config: DreamerConfig = DreamerConfig()):
        """Dreamer from ``"pixels"`` (the TWIST paper's pixel baselines)."""
        return cls(DreamerWorldModel.pixel_dreamer(action_dim, config.size, config.encoder),
                   action_dim, config, obs_key="pixels")

    @classmethod
    def for_pixels_state_recon(cls, action_dim: int, state_dim: int,
                               config: DreamerConfig = DreamerConfig()):
        """Dreamer State Recon. (TWIST baseline): acts from ``"pixels"``, its decoder
        reconstructs the privileged ``"state"`` of each step instead of the image."""
        return cls(DreamerWorldModel.pixel_state_recon(action_dim, state_dim, config.size,
                                                       config.encoder),
                   action_dim, config, obs_key="pixels", reconstruct_key="state")

    def policy(self, explore: bool = True, action_spec=None) -> DreamerPolicy:
        """The recurrent acting policy (reads ``self.obs_key``; needs ``make_primer()``).

        Args:
            explore: explore as ``config.exploration`` says (collection) or act with the
                actor's mode (evaluation).
            action_spec: the env's TorchRL action spec, checked against the actor's range:
                a Dreamer actor acts in ``[-1, 1]`` (tanh), the range it was trained in,
                so an env with other bounds is refused here rather than clipped silently.
        """
        check_unit_box(action_spec)
        return DreamerPolicy(self.world_model, self.actor, self.obs_key, self.obs_event_dims,
                             self.config.exploration_noise, explore,
                             sample=self.config.exploration == "sample")

    @property
    def device(self) -> torch.device:
        return module_device(self.world_model)

    def to(self, device: str | torch.device) -> DreamerAgent:
        """Moves every network (target critic included) to ``device``; returns ``self``.

        The optimisers keep training the moved parameters (see
        :func:`~simdist.utils.device.move_to_device`); ``update`` moves each batch there.
        """
        move_to_device([self.world_model, self.actor, self.critic, self.behaviour_loss,
                        self.model_loss],
                       [self.model_optim, self.actor_optim, self.critic_optim], device)
        return self

    def state_dict(self) -> dict:
        """Weights (target critic included) and optimiser states, for checkpoints."""
        return {"world_model": self.world_model.state_dict(), "actor": self.actor.state_dict(),
                "critic": self.critic.state_dict(),
                "target_critic": self.behaviour_loss.target_critic.state_dict(),
                "model_optim": self.model_optim.state_dict(),
                "actor_optim": self.actor_optim.state_dict(),
                "critic_optim": self.critic_optim.state_dict(),
                **self._running_statistics()}

    def load_state_dict(self, state: dict) -> None:
        self.world_model.load_state_dict(state["world_model"])
        self.actor.load_state_dict(state["actor"])
        self.critic.load_state_dict(state["critic"])
        self.behaviour_loss.target_critic.load_state_dict(state["target_critic"])
        for name, module in self._running_modules():
            module.load_state_dict(state[name])
        for name in ("model_optim", "actor_optim", "critic_optim"):
            getattr(self, name).load_state_dict(state[name])

    # -- self-describing checkpoints --------------------------------------------------
    def describe(self) -> dict:
        """What rebuilds this agent untrained: config fields, world-model parts, obs key."""
        out = {"agent": dataclasses.asdict(self.config),
               "world_model": describe_dreamer_model(self.world_model), "obs_key": self.obs_key}
        if self.reconstruct_key is not None:  # older files, without it, stay readable
            out["reconstruct_key"] = self.reconstruct_key
        return out

    def weights(self) -> dict:
        """Every network's state dict (target critic included), no optimiser state; with
        return normalisation or a standardised reconstruction also their running
        statistics, so a resumed run keeps them."""
        return {"world_model": self.world_model.state_dict(), "actor": self.actor.state_dict(),
                "critic": self.critic.state_dict(),
                "target_critic": self.behaviour_loss.target_critic.state_dict(),
                **self._running_statistics()}

    def _running_modules(self) -> list[tuple[str, torch.nn.Module]]:
        """The losses' running statistics that exist in this configuration, by name."""
        modules = (("return_scale", self.behaviour_loss.return_scale),
                   ("reconstruction_standardiser", self.model_loss.reconstruction_standardiser))
        return [(name, module) for name, module in modules if module is not None]

    def _running_statistics(self) -> dict:
        return {name: module.state_dict() for name, module in self._running_modules()}

    def save(self, path: str | os.PathLike, optimisers: bool = True,
             meta: dict | None = None) -> Path:
        """Writes one self-describing file (:mod:`simdist.agents.checkpoint`) that
        :meth:`load` reads back with no other file or code: the config and sizes, the
        weights and (``optimisers=True``) the optimiser states to continue training.
        ``meta`` is free-form plain data (e.g. ``{"task": "cartpole-balance"}``).

        Examples:
            >>> import tempfile
            >>> agent = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
            >>> path = agent.save(Path(tempfile.mkdtemp()) / "teacher.pt")
            >>> loaded = DreamerAgent.load(path)
            >>> loaded.config == agent.config, torch.equal(loaded.actor.net[0].weight,
            ...                                            agent.actor.net[0].weight)
            (True, True)
        """
        optim = {name: getattr(self, name).state_dict()
                 for name in ("model_optim", "actor_optim", "critic_optim")}
        return ckpt_format.write_agent_checkpoint(path, "DreamerAgent", self.describe(),
                                                  self.weights(), optim if optimisers else None,
                                                  meta)

    @classmethod
    def from_config(cls, config: dict, path="<checkpoint>") -> DreamerAgent:
        """An untrained agent from :meth:`describe`'s dict (errors name ``path``)."""
        wm = ckpt_format.build("world model", build_dreamer_model,
                               ckpt_format.part(config, path, "world_model"), path)
        agent_config = ckpt_format.config_from_dict(
            DreamerConfig, ckpt_format.part(config, path, "agent"), path, "DreamerConfig")
        obs_key = ckpt_format.part(config, path, "obs_key")
        return cls(wm, wm.rssm.action_dim, agent_config, obs_key=obs_key,
                   reconstruct_key=config.get("reconstruct_key"))

    def load_weights(self, weights: dict, path="<checkpoint>") -> None:
        """Loads :meth:`weights`' dict (strict; errors name ``path`` and the part)."""
        for name, module in (("world_model", self.world_model), ("actor", self.actor),
                             ("critic", self.critic),
                             ("target_critic", self.behaviour_loss.target_critic),
                             *self._running_modules()):
            if module is not None:
                ckpt_format.load_weights(module, ckpt_format.part(weights, path, name), path,
                                         name)

    @classmethod
    def from_checkpoint(cls, ckpt: dict, path="<checkpoint>", map_location=None) -> DreamerAgent:
        """An agent from a validated checkpoint dict (see :meth:`load`)."""
        agent = cls.from_config(ckpt["config"], path)
        agent.load_weights(ckpt["weights"], path)
        ckpt_format.load_optimisers(agent, ckpt, ("model_optim", "actor_optim", "critic_optim"), path)
        agent.checkpoint_meta = dict(ckpt.get("meta", {}))
        return agent.to(map_location) if map_location is not None else agent

    def make_primer(self) -> TensorDictPrimer:
        rssm = self.world_model.rssm
        return TensorDictPrimer(Composite({"agent": Composite({
            "belief": Unbounded((rssm.deter_dim,)), "stoch": Unbounded((rssm.stoch_dim,)),
            "prev_action": Unbounded((rssm.action_dim,))})}), default_value=0.0,
            expand_specs=True)

    def _step(self, loss, optim, params) -> None:
        optim.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(params, self.config.grad_clip)
        optim.step()

    def update_world_model(self, batch: TensorDictBase) -> TensorDictBase:
        """One world-model step on ``batch`` (on the agent's device); returns the loss
        terms and writes ``("posterior", ...)`` into ``batch`` for the actor-critic."""
        model_out = self.model_loss(batch)
        model_total = sum(v for k, v in model_out.items() if k.startswith("loss_"))
        self._step(model_total, self.model_optim, list(self.world_model.parameters()))
        return model_out

    def update_behaviour(self, batch: TensorDictBase) -> TensorDictBase:
        """One actor and one critic step in imagination from the posterior states of
        ``batch`` (``("posterior", "belief" / "stoch")``, written by
        :meth:`update_world_model` or, for a frozen world model, by ``self.model_loss``
        under ``torch.no_grad()``); the world model is not changed. Returns the terms."""
        if ("posterior", "belief") not in batch.keys(True):
            raise KeyError("update_behaviour: the batch has no ('posterior', 'belief'); run "
                           "update_world_model(batch) or self.model_loss(batch) first")
        behaviour = self.behaviour_loss(batch)
        self._step(behaviour["loss_actor"], self.actor_optim, list(self.actor.parameters()))
        self._step(behaviour["loss_critic"], self.critic_optim, list(self.critic.parameters()))
        self.behaviour_loss.update_target()
        return behaviour

    def update(self, batch: TensorDictBase) -> dict[str, float]:
        """One world-model step, then one actor and one critic step; returns the terms."""
        batch = batch.to(self.device)
        model_out = self.update_world_model(batch)
        behaviour = self.update_behaviour(batch)
        return {k: v.item() for k, v in (*model_out.items(), *behaviour.items())}


def check_unit_box(action_spec) -> None:
    """Raises ``ValueError`` unless ``action_spec`` (if given) bounds actions to ``[-1, 1]``.

    Examples:
        >>> from torchrl.data import Bounded
        >>> check_unit_box(Bounded(-1.0, 1.0, (2,)))
        >>> check_unit_box(Bounded(-2.0, 2.0, (2,)))
        Traceback (most recent call last):
        ...
        ValueError: a Dreamer actor acts in [-1, 1] (tanh), but action_spec bounds are [-2.0, -2.0] and [2.0, 2.0]; train and act in an env whose actions are normalised to [-1, 1]
    """
    if action_spec is None:
        return
    low, high = action_bounds(action_spec)
    if not (torch.equal(low, -torch.ones_like(low)) and torch.equal(high, torch.ones_like(high))):
        raise ValueError(f"a Dreamer actor acts in [-1, 1] (tanh), but action_spec bounds are "
                         f"{low.tolist()} and {high.tolist()}; train and act in an env whose "
                         "actions are normalised to [-1, 1]")
