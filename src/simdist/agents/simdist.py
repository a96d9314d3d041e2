"""SimDist agent: pretrain the latent world model, plan with MPPI, finetune the dynamics only.

``SimDistAgent.policy()`` is a TorchRL policy: it keeps the robot's observation history
in the TensorDict (``("simdist", "history")``, created/reset by :meth:`make_primer` with
``InitTracker`` marking episode starts; a new episode's window repeats its first
observation, exactly as :class:`~simdist.modules.HistoryEncoder` builds training windows),
encodes it, and plans with :class:`~simdist.modules.LatentMPPIPlanner` within the env's
per-joint action bounds.
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
from simdist.agents.describe import build_simdist_model, describe_simdist_model
from simdist.modules import SimDistWorldModel, WorldModelEnsemble
from simdist.modules.checks import check_finite
from simdist.modules.planner import LatentMPPIPlanner, PlannerConfig
from simdist.objectives import DynamicsFinetuneLoss, SimDistPretrainLoss
from simdist.utils.device import module_device, move_to_device
from simdist.utils.precision import autocast_dtype, check_precision


@dataclass
class SimDistConfig:
    """Training settings (reference: horizon 25, loss weights 1/1/1/4, Adam).

    Learning rates are constant: ``lr`` for pretraining, ``finetune_lr`` for the
    dynamics-only (and whole-model ablation) finetuning. The reference decays 2e-4 to 1e-4
    with a warm-up and a cosine schedule; that schedule is not implemented here (not
    measured either way at our CPU budgets of a few thousand updates).

    Examples:
        >>> config = SimDistConfig(size="tiny", horizon=3, finetune_lr=5e-5)
        >>> agent = SimDistAgent(SimDistWorldModel.build(10, 3, size=config.size), config)
        >>> agent.pretrain_loss.horizon, agent.finetune_optim.param_groups[0]["lr"]
        (3, 5e-05)
    """

    size: str = "small"
    horizon: int = 5
    lr: float = 2e-4
    finetune_lr: float = 1e-4
    grad_clip: float = 10.0
    bc_weight: float = 4.0
    # Value labels are discounted returns (~1/(1-gamma) times a reward): this weight
    # keeps their squared error from drowning the consistency term in the shared encoder.
    # (Adam makes the value head's own step size independent of it.)
    value_weight: float = 1.0
    # Dynamics-only finetuning through the frozen heads (DynamicsFinetuneLoss): recorded
    # target rewards on predicted latents, and the frozen value head on predicted vs
    # encoded latents. 0 and 0: the reference's consistency-only finetuning.
    finetune_reward_weight: float = 0.0
    finetune_value_weight: float = 0.0
    # the finetuning's consistency term (DynamicsFinetuneLoss(consistency=)): "squared"
    # (the pretraining's term, the reference) or "kl" (each SimNorm group's KL divergence).
    finetune_consistency: str = "squared"
    # dynamics modules pretrained together on the shared encoder and heads (a dynamics
    # ensemble; SimDistPretrainLoss(extra_dynamics=)). 1: the single model. The extra
    # ones live in ``pretrain_loss.extra_dynamics``; :meth:`SimDistAgent.members` gives
    # one world model per dynamics, sharing everything else.
    dynamics_members: int = 1
    # "bfloat16": pretraining and finetuning updates run their forward pass under
    # ``torch.autocast`` (matmuls in bfloat16, weights, optimiser state and latents in
    # float32; DreamerV3 trains this way). 1.8-2.6x the updates/s on CPUs with AVX512-BF16
    # (benchmarks/simdist_pretrain_precision.py), 16-25x slower on CPUs with AVX2 only.
    # "auto": bfloat16 where the device has native bfloat16 matmuls, else float32
    # (simdist.utils.precision). Planning has its own setting (PlannerConfig.precision).
    # "none": float32 throughout.
    mixed_precision: str = "none"


# the actions a latency-compensating policy has sent that the robot may not apply yet
PENDING = ("simdist", "pending_actions")
# the action sent at the previous step (for an encoder that reads it beside each observation)
PREVIOUS_ACTION = ("simdist", "previous_action")


def previous_action_of(td: TensorDictBase, encoder) -> torch.Tensor | None:
    """The previous action ``td`` carries for an encoder that reads it (``None`` for one
    that does not); a clear error when the env was built without its primer."""
    if not encoder.action_dim:
        return None
    previous = td.get(PREVIOUS_ACTION, None)
    if previous is None:
        raise KeyError(f"this model's encoder reads the previous action: the env needs "
                       f"{PREVIOUS_ACTION} (build it with SimDistAgent.make_primer())")
    return previous


class SimDistPolicy(TensorDictModuleBase):
    """Observation history -> latent -> latent MPPI plan -> action.

    Examples:
        >>> agent = SimDistAgent(SimDistWorldModel.build(10, 3, size="tiny", history=2))
        >>> planner = PlannerConfig(horizon=2, num_samples=8, num_elites=2, iterations=1)
        >>> policy = agent.policy(-torch.ones(3), torch.ones(3), planner)
        >>> td = policy(TensorDict({"observation": torch.zeros(4, 10),
        ...                         "is_init": torch.ones(4, 1, dtype=torch.bool)}, [4]))
        >>> td["action"].shape, td["next", "simdist", "history"].shape
        (torch.Size([4, 3]), torch.Size([4, 2, 10]))
    """

    def __init__(self, world_model: SimDistWorldModel, planner: LatentMPPIPlanner,
                 obs_key="observation", latency_compensation: int = 0,
                 command_index: int = -1):
        super().__init__()
        self.world_model, self.planner, self.obs_key = world_model, planner, obs_key
        self.latency_compensation = int(latency_compensation)
        # where the observation holds the command (the quadruped's layouts put it last);
        # read only with PlannerConfig.proposal_commands
        obs_dim = world_model.encoder.obs_dim
        if not -obs_dim <= command_index < obs_dim:
            raise ValueError(f"command_index {command_index} is outside the observation "
                             f"({obs_dim} entries)")
        self.command_index = command_index % obs_dim
        self.in_keys = [obs_key, "is_init", ("simdist", "history")]
        self.out_keys = ["action", ("next", "simdist", "history"), ("planner", "latent"),
                         ("planner", "mean"), ("planner", "rewards"), ("planner", "value")]
        if self.latency_compensation:
            self.in_keys.append(PENDING)
            self.out_keys.append(("next", *PENDING))
        if world_model.encoder.action_dim:
            self.in_keys.append(PREVIOUS_ACTION)
            self.out_keys.append(("next", *PREVIOUS_ACTION))

    def _in_flight(self, td, latent, is_init, device) -> tuple[torch.Tensor, torch.Tensor]:
        """The latent rolled through the actions still in flight, and those actions."""
        k, action_dim = self.latency_compensation, self.world_model.action_dim
        pending = td.get(PENDING, None)
        if pending is None:
            raise KeyError(f"latency_compensation={k} needs {PENDING} in the env: build it "
                           f"with SimDistAgent.make_primer(latency_compensation={k})")
        pending = pending.to(device).reshape(-1, k, action_dim)
        # an episode starts with nothing in flight (the simulator's delay line holds zeros)
        pending = torch.where(is_init.reshape(-1, 1, 1), torch.zeros_like(pending), pending)
        return self.world_model.rollout(latent, pending)[..., -1, :], pending

    def _command_latents(self, td, history, commands, is_init, device) -> torch.Tensor:
        """``[N, C, L]``: the history encoded once per command of ``commands`` (its command
        entry replaced at every step of the window), rolled through the actions in flight
        like the episode's own latent."""
        windows = history.reshape(-1, *history.shape[-2:])
        n, c = windows.shape[0], len(commands)
        windows = windows[:, None].repeat(1, c, 1, 1)
        windows[..., self.command_index] = torch.tensor(
            commands, dtype=windows.dtype, device=device)[:, None]
        latents = self.world_model.encode(windows)  # [N, C, L]
        if self.latency_compensation:
            latents = torch.stack([self._in_flight(td, latents[:, i], is_init, device)[0]
                                   for i in range(c)], 1)
        return latents

    @staticmethod
    def replace_action(td: TensorDictBase, action: torch.Tensor) -> TensorDictBase:
        """Sets ``td["action"]`` to ``action`` *and* the state this policy carries to the
        next step about the action sent (the previous action an encoder reads, the newest
        action in flight): what a wrapper that changes the planned action (exploration
        noise, another controller) must call, so the next step encodes what was sent.

        Examples:
            >>> agent = SimDistAgent(SimDistWorldModel.build(10, 3, size="tiny",
            ...                                              previous_action=True))
            >>> planner = PlannerConfig(horizon=2, num_samples=8, num_elites=2, iterations=1)
            >>> policy = agent.policy(config=planner)
            >>> td = policy(TensorDict({"observation": torch.zeros(1, 10),
            ...                         "is_init": torch.ones(1, 1, dtype=torch.bool),
            ...                         "simdist": {"previous_action": torch.zeros(1, 3)}}, [1]))
            >>> td = SimDistPolicy.replace_action(td, torch.ones(1, 3))
            >>> td["next", "simdist", "previous_action"].tolist()
            [[1.0, 1.0, 1.0]]
        """
        td.set("action", action)
        if ("next", *PREVIOUS_ACTION) in td.keys(True):
            td.set(("next", *PREVIOUS_ACTION), action.clone())
        if ("next", *PENDING) in td.keys(True):
            sent = td.get(("next", *PENDING)).clone()
            sent[..., -1, :] = action
            td.set(("next", *PENDING), sent)
        return td

    @torch.no_grad()
    def forward(self, td: TensorDictBase) -> TensorDictBase:
        enc = self.world_model.encoder
        obs = td.get(self.obs_key)
        check_finite(self.obs_key, obs)  # named here, not as a non-finite latent later
        # Inputs to the model's device, outputs back to the env's (a GPU model, CPU env).
        home, device = obs.device, module_device(self.world_model)
        obs = obs.to(device)
        # an unbatched env (make_env's default) gives batch == (): reshapes take tuples,
        # which may be empty, not unpacked arguments
        batch = obs.shape[:-1]
        is_init = td.get("is_init", None)
        if is_init is None:
            raise KeyError("SimDistPolicy needs 'is_init': add torchrl.envs.InitTracker()")
        is_init = is_init.to(device).reshape(*batch, 1, 1).bool()
        previous = previous_action_of(td, enc)
        previous = None if previous is None else previous.to(device)
        history = td.get(("simdist", "history"), None)
        history = enc.push(None if history is None else history.to(device), obs, previous,
                           is_init[..., 0])
        latent = self.world_model.encode(history).reshape(-1, self.world_model.latent_dim)
        start = latent
        if self.latency_compensation:
            start, pending = self._in_flight(td, latent, is_init, device)
        inputs = TensorDict({"latent": start, "is_init": is_init.reshape(-1, 1)},
                            [latent.shape[0]])
        commands = self.planner.config.proposal_commands
        if commands and self.planner.config.num_policy:
            inputs["proposal_latent"] = self._command_latents(td, history, commands, is_init,
                                                              device)
        plan = self.planner(inputs)
        if self.latency_compensation:
            sent = torch.cat([pending[:, 1:], plan["action"][:, None]], 1)
            td.set(("next", *PENDING), sent.reshape(batch + sent.shape[1:]).to(home))
        td.set("action", plan["action"].reshape(*batch, -1).to(home))
        if enc.action_dim:
            td.set(("next", *PREVIOUS_ACTION), td.get("action").clone())
        td.set(("next", "simdist", "history"), history.to(home))
        td.set(("planner", "latent"), latent.reshape(*batch, -1).to(home))
        for key in ("mean", "rewards", "value"):
            value = plan["planner", key]
            td.set(("planner", key), value.reshape(batch + value.shape[1:]).to(home))
        return td


class SimDistAgent(ckpt_format.LoadableAgent):
    """Owns the world model, its two losses and their optimisers.

    ``pretrain_update`` trains everything on simulation slices; ``finetune_update``
    trains the dynamics alone on target-domain slices (its optimiser only holds the
    dynamics' parameters, and the loss never builds a graph through the other parts).
    ``finetune_whole_update`` is the ablation that finetunes every part.

    Examples:
        >>> agent = SimDistAgent(SimDistWorldModel.build(10, 3, size="tiny"))
        >>> len(agent.finetune_optim.param_groups[0]["params"]) == len(list(agent.world_model.dynamics.parameters()))
        True
    """

    def __init__(self, world_model: SimDistWorldModel, config: SimDistConfig = SimDistConfig(),
                 planner_config: PlannerConfig | None = None):
        self.world_model, self.config = world_model, config
        # the planner :meth:`policy` uses by default; saved with the agent
        self.planner_config = planner_config
        if config.dynamics_members < 1:
            raise ValueError(f"dynamics_members must be >= 1, got {config.dynamics_members}")
        check_precision(config.mixed_precision, "mixed_precision")
        extra = [world_model.fresh_dynamics() for _ in range(config.dynamics_members - 1)]
        self.pretrain_loss = SimDistPretrainLoss(world_model, horizon=config.horizon,
                                                 bc_weight=config.bc_weight,
                                                 value_weight=config.value_weight,
                                                 extra_dynamics=extra)
        # one finetuning loss per dynamics member (the first: ``finetune_loss``)
        self.finetune_losses = [
            DynamicsFinetuneLoss(member, horizon=config.horizon,
                                 reward_weight=config.finetune_reward_weight,
                                 value_weight=config.finetune_value_weight,
                                 consistency=config.finetune_consistency)
            for member in self.members()]
        self.finetune_loss = self.finetune_losses[0]
        self.pretrain_optim = torch.optim.Adam(self.pretrain_loss.trainable_parameters(),
                                               lr=config.lr)
        self.finetune_optim = torch.optim.Adam(
            [p for loss in self.finetune_losses for p in loss.trainable_parameters()],
            lr=config.finetune_lr)
        self.whole_optim = torch.optim.Adam(self.pretrain_loss.trainable_parameters(),
                                            lr=config.finetune_lr)

    @property
    def device(self) -> torch.device:
        return module_device(self.world_model)

    def to(self, device: str | torch.device) -> SimDistAgent:
        """Moves the world model to ``device`` (its optimisers follow, see
        :func:`~simdist.utils.device.move_to_device`); the updates move each batch there.
        Returns ``self``."""
        move_to_device([self.world_model, self.pretrain_loss.extra_dynamics],
                       [self.pretrain_optim, self.finetune_optim, self.whole_optim], device)
        return self

    def members(self) -> list[SimDistWorldModel]:
        """One world model per pretrained dynamics (``config.dynamics_members``), the
        first being :attr:`world_model`; all share its encoder and heads."""
        return [self.world_model, *(self.world_model.with_dynamics(d)
                                    for d in self.pretrain_loss.extra_dynamics)]

    def _apply(self, total, optim) -> None:
        optim.zero_grad(set_to_none=True)
        total.backward()
        params = [p for group in optim.param_groups for p in group["params"]]
        torch.nn.utils.clip_grad_norm_(params, self.config.grad_clip)
        optim.step()

    def _autocast(self):
        """The forward pass's precision context (``config.mixed_precision``)."""
        dtype = autocast_dtype(self.config.mixed_precision, self.device)
        return torch.autocast(self.device.type, dtype=dtype, enabled=dtype is not None)

    def pretrain_update(self, batch: TensorDictBase) -> dict[str, float]:
        batch = batch.to(self.device)
        with self._autocast():
            out = self.pretrain_loss(batch)
        self._apply(sum(v for k, v in out.items() if k.startswith("loss_")), self.pretrain_optim)
        return {k: v.item() for k, v in out.items()}

    def _finetune(self, batch: TensorDictBase, whole_model: bool, optim,
                  slice_errors: bool = False):
        """Every member's finetuning loss on ``batch``, their mean applied; the metrics
        are the members' means (with ``slice_errors``, also each slice's consistency
        error before the step, averaged over members)."""
        batch = batch.to(self.device)
        with self._autocast():
            outs = [loss.consistency_all_parts(batch) if whole_model else loss(batch)
                    for loss in self.finetune_losses]
        total = sum(v for out in outs for k, v in out.items() if k.startswith("loss_"))
        self._apply(total / len(outs), optim)
        metrics = {k: sum(out[k].item() for out in outs) / len(outs) for k in outs[0].keys()
                   if k != "slice_error"}
        if not slice_errors:
            return metrics
        return metrics, sum(out["slice_error"].float().cpu() for out in outs) / len(outs)

    def finetune_update(self, batch: TensorDictBase, *, slice_errors: bool = False):
        """SimDist's finetuning: the dynamics (every member's, with
        ``config.dynamics_members`` > 1) on target slices; nothing else moves.

        Returns the step's metrics; with ``slice_errors``, ``(metrics, errors)`` where
        ``errors`` (``[slices]``) is each slice's consistency error (the priorities of
        :class:`~simdist.data.prioritised_slices.PrioritisedSlices`)."""
        return self._finetune(batch, False, self.finetune_optim, slice_errors)

    def finetune_whole_update(self, batch: TensorDictBase, *, slice_errors: bool = False):
        """Ablation: the finetuning loss on target data with every part trainable.

        Target data carries no value labels, so by default the ablation uses the
        consistency term alone but lets it move the encoder (the heads' shared latent);
        with ``finetune_reward_weight``/``finetune_value_weight`` the head terms train the
        heads as well. ``slice_errors`` as in :meth:`finetune_update`.
        """
        return self._finetune(batch, True, self.whole_optim, slice_errors)

    @torch.no_grad()
    def finetune_slice_errors(self, batch: TensorDictBase) -> torch.Tensor:
        """Each slice's consistency error under the current dynamics (members' mean),
        ``[slices]``, without a step: the starting priorities of prioritised finetuning."""
        batch = batch.to(self.device)
        with self._autocast():
            errors = [loss(batch)["slice_error"].float().cpu() for loss in self.finetune_losses]
        return sum(errors) / len(errors)

    def policy(self, action_low=None, action_high=None, config: PlannerConfig | None = None,
               seed: int = 0, compile: bool = False, *, action_spec=None,
               command_index: int = -1) -> SimDistPolicy:
        """A planning policy over this world model within the env's action bounds.

        Args:
            action_low: per-dimension lower bounds ``[A]`` (with ``action_high``), or
                give ``action_spec`` instead. With neither, the planner config's scalar
                bounds apply.
            action_high: per-dimension upper bounds ``[A]``.
            config: the planner (default: ``self.planner_config``, which :meth:`load`
                restores, else ``PlannerConfig()``).
            seed: seeds the planner's sampling noise.
            compile: ``torch.compile`` the planning loop.
            action_spec: the env's TorchRL action spec (``env.action_spec``, batched or
                not; see :func:`~simdist.agents.action_spec.action_bounds`).
            command_index: the observation entry holding the command, which
                ``config.proposal_commands`` replaces (the quadruped tasks put it last).

        Examples:
            >>> from torchrl.data import Bounded
            >>> agent = SimDistAgent(SimDistWorldModel.build(10, 3, size="tiny"))
            >>> policy = agent.policy(action_spec=Bounded(-0.5, 0.5, (8, 3)))
            >>> policy.planner.action_high
            tensor([0.5000, 0.5000, 0.5000])
        """
        if action_spec is not None:
            if action_low is not None or action_high is not None:
                raise ValueError("pass action_spec or action_low/action_high, not both")
            action_low, action_high = action_bounds(action_spec)
        elif (action_low is None) != (action_high is None):
            raise ValueError("pass both action_low and action_high (or an action_spec)")
        config = config or self.planner_config or PlannerConfig()
        # a dynamics ensemble plans as one model (WorldModelEnsemble over the members)
        model = self.world_model if len(self.pretrain_loss.extra_dynamics) == 0 else \
            WorldModelEnsemble(self.members())
        planner = LatentMPPIPlanner.from_world_model(
            model, config, seed=seed, compile=compile,
            action_bounds=None if action_low is None else (action_low, action_high))
        return SimDistPolicy(model, planner, latency_compensation=config.latency_compensation,
                             command_index=command_index).to(self.device)

    # -- self-describing checkpoints --------------------------------------------------
    def describe(self) -> dict:
        """What rebuilds this agent untrained: config fields, model sizes, planner."""
        planner = self.planner_config
        return {"agent": dataclasses.asdict(self.config),
                "world_model": describe_simdist_model(self.world_model),
                "planner": None if planner is None else dataclasses.asdict(planner)}

    def save(self, path: str | os.PathLike, optimisers: bool = True,
             meta: dict | None = None) -> Path:
        """Writes one self-describing file (:mod:`simdist.agents.checkpoint`) that
        :meth:`load` reads back with no other file or code: sizes, configs (the planner's
        too), weights (encoder normalisation included) and, with ``optimisers``, the
        optimiser states. ``meta`` is free-form plain data (e.g. the task).

        Examples:
            >>> import tempfile
            >>> agent = SimDistAgent(SimDistWorldModel.build(10, 3, size="tiny"),
            ...                      planner_config=PlannerConfig(horizon=2, num_samples=8,
            ...                                                   num_elites=2))
            >>> path = agent.save(Path(tempfile.mkdtemp()) / "simdist.pt")
            >>> loaded = SimDistAgent.load(path)
            >>> loaded.planner_config.horizon, loaded.world_model.encoder.history
            (2, 2)
        """
        optim = {name: getattr(self, name).state_dict()
                 for name in ("pretrain_optim", "finetune_optim", "whole_optim")}
        weights = {"world_model": self.world_model.state_dict()}
        if len(self.pretrain_loss.extra_dynamics):  # the other members of a dynamics ensemble
            weights["extra_dynamics"] = self.pretrain_loss.extra_dynamics.state_dict()
        return ckpt_format.write_agent_checkpoint(
            path, "SimDistAgent", self.describe(), weights, optim if optimisers else None, meta)

    @classmethod
    def from_checkpoint(cls, ckpt: dict, path="<checkpoint>", map_location=None) -> SimDistAgent:
        """An agent from a validated checkpoint dict (see :meth:`load`)."""
        config = ckpt["config"]
        wm = ckpt_format.build("world model", build_simdist_model,
                               ckpt_format.part(config, path, "world_model"), path)
        agent_config = ckpt_format.config_from_dict(
            SimDistConfig, ckpt_format.part(config, path, "agent"), path, "SimDistConfig")
        planner = config.get("planner")
        planner = None if planner is None else ckpt_format.config_from_dict(
            PlannerConfig, planner, path, "PlannerConfig")
        agent = cls(wm, agent_config, planner_config=planner)
        ckpt_format.load_weights(wm, ckpt_format.part(ckpt, path, "weights", "world_model"),
                                 path, "world_model")
        if agent_config.dynamics_members > 1:
            ckpt_format.load_weights(agent.pretrain_loss.extra_dynamics,
                                     ckpt_format.part(ckpt, path, "weights", "extra_dynamics"),
                                     path, "extra_dynamics")
        ckpt_format.load_optimisers(agent, ckpt, ("pretrain_optim", "finetune_optim", "whole_optim"), path)
        agent.checkpoint_meta = dict(ckpt.get("meta", {}))
        return agent.to(map_location) if map_location is not None else agent

    def make_primer(self, latency_compensation: int | None = None) -> TensorDictPrimer:
        """The env transform that carries the policy's state between steps: the
        observation history, the action sent at the previous step when the encoder reads
        it, and, with ``latency_compensation=k`` (default: the planner config's), the
        last ``k`` actions sent."""
        enc = self.world_model.encoder
        if latency_compensation is None:
            latency_compensation = (self.planner_config or PlannerConfig()).latency_compensation
        specs = {"history": Unbounded((enc.history, enc.input_dim))}
        if enc.action_dim:
            specs[PREVIOUS_ACTION[-1]] = Unbounded((enc.action_dim,))
        if latency_compensation:
            specs[PENDING[-1]] = Unbounded((latency_compensation, self.world_model.action_dim))
        return TensorDictPrimer(Composite({"simdist": Composite(specs)}), default_value=0.0,
                                expand_specs=True)
