"""Asymmetric SAC (Pinto et al. 2018), TWIST's model-free baseline: the actor reads
pixels, the critic reads the privileged state of the same step.

Built on TorchRL's ``SACLoss`` (two Q-nets, learned entropy temperature, Polyak targets
with ``SoftUpdate``): the asymmetry is only which keys each network reads, since TorchRL
losses call each network on its own ``in_keys``.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import NormalParamExtractor, TensorDictModule, TensorDictModuleBase
from torch import nn
from torchrl.data import Bounded, Composite, Unbounded
from torchrl.envs import TensorDictPrimer
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal
from torchrl.objectives import SACLoss, SoftUpdate

from simdist.agents import checkpoint as ckpt_format
from simdist.agents.dreamer import check_unit_box
from simdist.experts.networks import make_critic
from simdist.modules import PixelEncoder, RandomShift
from simdist.modules.checks import check_finite
from simdist.objectives.common import check_pixels
from simdist.utils.device import module_device


@dataclass
class AsymmetricSACConfig:
    """Settings of :class:`AsymmetricSACAgent` (DrQ-style random shift on the actor's
    images, as pixel SAC needs on a small budget).

    The defaults are the plainest form (one image, 1-step target). The TWIST recipe's
    baseline uses ``frames=3, n_step=3, tau=0.02`` (DrQ-v2's stack and n-step return):
    measured on cartpole-balance without DR at 3000 updates, that learns to balance from
    pixels on its training scene (976 of ~1000) where ``frames=3`` alone scores 339,
    near random actions (docs/findings.md, "Asymmetric SAC that balances").

    Examples:
        >>> AsymmetricSACConfig().shift_pad
        4
    """

    depth: int = 16  # first-layer channels of the actor's CNN (PixelEncoder)
    hidden: int = 256  # actor head and critic MLP widths
    lr: float = 3e-4
    gamma: float = 0.99
    tau: float = 0.005
    alpha_init: float = 0.1
    shift_pad: int = 4
    # the actor reads the last `frames` images stacked on the channel axis (DrQ: 3), so
    # that it can see motion: one image holds no velocity. 1: the current image alone.
    frames: int = 1
    # the critic's target sums this many discounted rewards before it bootstraps (DrQ-v2:
    # 3). With few updates a 1-step target carries reward back ~tau * updates steps; n
    # steps carry it n times as far (with tau 0.02 the recipe's pixel baseline learns
    # cartpole at 3000 updates; with 1 and 0.005 it does not: docs/findings.md)
    n_step: int = 1
    # LayerNorm on the critic's state input. Off: on cartpole's 5-d state it erases each
    # sample's mean and scale, and SAC from the state then does not learn (state SAC,
    # 11000 updates: 234 with it, training episodes up to 994 without; docs/findings.md)
    critic_layer_norm: bool = False

    def __post_init__(self):
        if self.frames < 1 or self.n_step < 1:
            raise ValueError(f"frames and n_step must be >= 1, got {self.frames} and "
                             f"{self.n_step}")
        if not 0.0 < self.tau <= 1.0:
            raise ValueError(f"tau must be in (0, 1], got {self.tau}")


def transitions_from_slices(batch: TensorDictBase, frames: int = 1, n_step: int = 1,
                            gamma: float = 0.99) -> TensorDict:
    """``[B, T]`` slices of stored steps (only ``("next", ...)`` observations are kept)
    -> ``[N]`` transitions ``(o_t, s_t, a_t, R, o_{t+m}, s_{t+m}, done, m)``.

    Step ``t``'s observation is step ``t - 1``'s ``next`` one, so each slice gives
    ``T - frames - n_step + 1`` transitions; one whose frames would reach back past the
    start of its episode (an ``is_init`` step among the last ``frames``) cannot be rebuilt
    this way and is dropped. With ``frames = k > 1`` the pixels of a transition are the last
    ``k`` observations, ``[N, k, H, W, C]`` oldest first (``o_{t+1}``'s stack is ``o_t``'s
    shifted by one); the state stays the current step's.

    With ``n_step = n > 1`` the reward is ``R = sum_{i<m} gamma^i r_{t+i}`` over ``m <= n``
    steps and the next observation is ``o_{t+m}``: ``m`` is ``n`` unless the episode
    terminates first (``m`` ends at the terminal step, ``done`` is set) or is cut by the
    start of the next one (``m`` ends before it and the target bootstraps there).
    ``"steps_to_next_obs"`` holds ``m``, which TorchRL's TD(0) estimator reads as the
    power of ``gamma`` for the bootstrap.

    Examples:
        >>> b = TensorDict({"action": torch.arange(6.).reshape(2, 3, 1),
        ...     "is_init": torch.zeros(2, 3, 1, dtype=torch.bool),
        ...     "next": {"state": torch.arange(6.).reshape(2, 3, 1) + 10,
        ...              "pixels": torch.zeros(2, 3, 64, 64, 3, dtype=torch.uint8),
        ...              "reward": torch.ones(2, 3, 1),
        ...              "terminated": torch.zeros(2, 3, 1, dtype=torch.bool)}}, [2, 3])
        >>> t = transitions_from_slices(b)
        >>> t["state"].flatten().tolist(), t["action"].flatten().tolist()
        ([10.0, 11.0, 13.0, 14.0], [1.0, 2.0, 4.0, 5.0])
        >>> t = transitions_from_slices(b, frames=2)
        >>> t["pixels"].shape, t["state"].flatten().tolist(), t["action"].flatten().tolist()
        (torch.Size([2, 2, 64, 64, 3]), [11.0, 14.0], [2.0, 5.0])
        >>> t = transitions_from_slices(b, n_step=2, gamma=0.5)
        >>> t["next", "reward"].flatten().tolist(), t["next", "state"].flatten().tolist()
        ([1.5, 1.5], [12.0, 15.0])
    """
    if frames < 1 or n_step < 1:
        raise ValueError(f"frames and n_step must be >= 1, got {frames} and {n_step}")
    if batch.ndim != 2 or batch.shape[1] < frames + n_step:
        raise ValueError(f"need [slices, steps >= {frames + n_step}] slices for {frames} "
                         f"frame(s) and {n_step}-step returns, got batch shape {batch.shape}")
    nxt, steps = batch["next"], batch.shape[1] - frames - n_step + 1
    # window j holds observations j .. j + frames - 1 (the "next" ones of those steps)
    # and acts at step j + frames; its return runs over steps j + frames .. + n_step - 1
    windows = torch.arange(frames)[None, :] + torch.arange(steps)[:, None]  # [steps, k]
    now = windows[:, -1]
    ahead = now[:, None] + 1 + torch.arange(n_step)  # [steps, n] the return's steps
    init = batch["is_init"].reshape(batch.shape).bool()
    ended = nxt["terminated"].reshape(batch.shape).bool()[:, ahead]  # [B, steps, n]
    # step i of the return counts if no earlier one terminated and it is not the start
    # of a new episode (step 0 always: a transition starting an episode is dropped below)
    counts = ~init[:, ahead]
    counts[..., 0] = True
    counts[..., 1:] &= ~ended[..., :-1]
    counts = counts.cumprod(-1).bool()
    m = counts.sum(-1)  # [B, steps] in 1 .. n_step
    discount = gamma ** torch.arange(n_step, dtype=nxt["reward"].dtype)
    reward = nxt["reward"].reshape(*batch.shape, -1)[:, ahead]  # [B, steps, n, 1]
    reward = (reward * (discount[:, None] * counts[..., None])).sum(2)
    terminated = (ended & counts).any(-1, keepdim=True)
    last = (m - 1)[..., None]  # offset of the step whose "next" observation is o_{t+m}
    rows = torch.arange(batch.shape[0])[:, None, None]
    pixels = nxt["pixels"]
    if frames == 1:  # the single-frame actor reads [H, W, C] images
        obs, next_obs = pixels[:, now], pixels[rows[..., 0], now + m]
    else:
        obs, next_obs = pixels[:, windows], pixels[rows, windows + last + 1]
    out = TensorDict({
        "pixels": obs, "state": nxt["state"][:, now],
        "action": batch["action"][:, now + 1],
        "steps_to_next_obs": m[..., None].to(reward.dtype),
        "next": {"pixels": next_obs, "state": nxt["state"][rows[..., 0], now + m],
                 "reward": reward, "terminated": terminated,
                 "done": terminated.clone()}}, [batch.shape[0], steps])
    keep = ~init[:, windows + 1].any(-1)  # none of steps j + 1 .. j + frames starts an episode
    return out[keep]


class StackedFrames(nn.Module):
    """``[..., k, H, W, C]`` frames -> ``[..., H, W, k * C]`` (one image of stacked channels).

    Examples:
        >>> StackedFrames()(torch.zeros(2, 3, 64, 64, 3)).shape
        torch.Size([2, 64, 64, 9])
    """

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        moved = frames.movedim(-4, -2)  # [..., H, W, k, C]
        return moved.reshape(*moved.shape[:-2], moved.shape[-2] * moved.shape[-1])


class AsymmetricSACAgent(ckpt_format.LoadableAgent):
    """Pixel actor, state critic, trained with TorchRL's ``SACLoss`` on stored slices.

    ``update(batch)`` takes ``[B, T]`` slices as :class:`~simdist.pipelines.EpisodeReplay`
    samples them (so :func:`~simdist.pipelines.train_dreamer_online` can train it);
    ``policy()`` acts from ``"pixels"`` alone, as a deployed robot would. ``save(path)``
    writes one self-describing file that :func:`~simdist.agents.load_agent` and
    ``recipes/evaluate.py`` read back.

    Args:
        state_dim: the privileged state's size (the critic's input).
        action_dim: actions in ``[-1, 1]``.
        config: :class:`AsymmetricSACConfig`.

    Examples:
        >>> agent = AsymmetricSACAgent(5, 1, AsymmetricSACConfig(depth=4, hidden=16))
        >>> b = TensorDict({"action": torch.zeros(2, 3, 1),
        ...     "is_init": torch.zeros(2, 3, 1, dtype=torch.bool),
        ...     "next": {"state": torch.zeros(2, 3, 5),
        ...              "pixels": torch.zeros(2, 3, 64, 64, 3, dtype=torch.uint8),
        ...              "reward": torch.ones(2, 3, 1),
        ...              "terminated": torch.zeros(2, 3, 1, dtype=torch.bool)}}, [2, 3])
        >>> sorted(k for k in agent.update(b) if k.startswith("loss"))
        ['loss_actor', 'loss_alpha', 'loss_qvalue']
    """

    #: what the deployed policy reads (``recipes/evaluate.py`` renders pixels for it)
    obs_key = "pixels"

    def __init__(self, state_dim: int, action_dim: int,
                 config: AsymmetricSACConfig = AsymmetricSACConfig()):
        self.config, self.state_dim, self.action_dim = config, state_dim, action_dim
        encoder = PixelEncoder(config.depth, norm="layer", input_norm="image",
                               channels=3 * config.frames)
        stack = [StackedFrames()] if config.frames > 1 else []
        net = nn.Sequential(*stack, encoder, MLP(in_features=encoder.embed_dim,
                                         out_features=2 * action_dim,
                                         num_cells=[config.hidden], activation_class=nn.ELU),
                            NormalParamExtractor(scale_mapping="biased_softplus_1.0",
                                                 scale_lb=1e-3))
        spec = Bounded(-1.0, 1.0, (action_dim,))
        self.actor = ProbabilisticActor(
            TensorDictModule(net, in_keys=["pixels"], out_keys=["loc", "scale"]),
            in_keys=["loc", "scale"], spec=spec, distribution_class=TanhNormal,
            distribution_kwargs={"low": spec.space.low, "high": spec.space.high},
            return_log_prob=False)
        critic = make_critic(state_dim, action_dim, config.hidden, obs_key="state",
                             layer_norm=config.critic_layer_norm)
        self.loss = SACLoss(self.actor, critic, num_qvalue_nets=2, loss_function="l2",
                            alpha_init=config.alpha_init)
        self.loss.make_value_estimator(gamma=config.gamma)
        self.updater = SoftUpdate(self.loss, tau=config.tau)
        self.optim = torch.optim.Adam(self.loss.parameters(), lr=config.lr)
        # one shift per stack of frames (DrQ), so the motion between them stays the camera's
        per = "frame" if config.frames == 1 else "sequence"
        self.shift = RandomShift(config.shift_pad, per) if config.shift_pad else None

    def update(self, batch: TensorDictBase) -> dict[str, float]:
        """One SAC step on the transitions inside ``[B, T]`` slices
        (``T >= frames + n_step``)."""
        # the windows are cut where the replay keeps its slices (the CPU), then moved
        data = transitions_from_slices(batch, self.config.frames, self.config.n_step,
                                       self.config.gamma).to(module_device(self.loss))
        if self.shift is not None:  # the actor's images only; the critic reads the state
            data.set("pixels", self.shift(data["pixels"]))
            data.set(("next", "pixels"), self.shift(data["next", "pixels"]))
        out = self.loss(data)
        total = out["loss_actor"] + out["loss_qvalue"] + out["loss_alpha"]
        check_finite("asymmetric SAC loss", total)
        self.optim.zero_grad(set_to_none=True)
        total.backward()
        self.optim.step()
        self.updater.step()
        return {k: float(v.detach().mean()) for k, v in out.items()}

    def policy(self, explore: bool = True, action_spec=None) -> AsymmetricSACPolicy:
        """Pixels -> action with the trained actor (a sample when ``explore``, else the
        distribution's deterministic action)."""
        check_unit_box(action_spec)
        return AsymmetricSACPolicy(self.loss, explore, self.config.frames)

    def make_primer(self) -> TensorDictPrimer | None:
        """The env's primer for the previous ``frames - 1`` images (``("agent",
        "frames")``); ``None`` for a single-frame actor, which carries nothing."""
        if self.config.frames == 1:
            return None
        return TensorDictPrimer(Composite({"agent": Composite({"frames": Unbounded(
            (self.config.frames - 1, 64, 64, 3), dtype=torch.uint8)})}),
            default_value=0, expand_specs=True)

    def state_dict(self) -> dict:
        return {"loss": self.loss.state_dict(), "optim": self.optim.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.loss.load_state_dict(state["loss"])
        self.optim.load_state_dict(state["optim"])

    def to(self, device) -> AsymmetricSACAgent:
        """Moves the actor, critics, targets and temperature (the optimiser follows its
        parameters, which move in place)."""
        self.loss.to(device)
        return self

    # -- self-describing checkpoints --------------------------------------------------
    def save(self, path: str | os.PathLike, optimisers: bool = True,
             meta: dict | None = None) -> Path:
        """Writes one self-describing file: sizes, config, the loss's weights (actor,
        both Q-nets, their targets, the temperature) and, unless ``optimisers=False``,
        the optimiser. ``meta`` is free-form plain data (e.g. the task).

        Examples:
            >>> import tempfile
            >>> agent = AsymmetricSACAgent(5, 1, AsymmetricSACConfig(depth=4, hidden=16))
            >>> path = agent.save(Path(tempfile.mkdtemp()) / "sac.pt", meta={"task": "x"})
            >>> loaded = AsymmetricSACAgent.load(path)
            >>> loaded.config.depth, loaded.checkpoint_meta["task"]
            (4, 'x')
        """
        config = {"sac": dataclasses.asdict(self.config), "state_dim": self.state_dim,
                  "action_dim": self.action_dim}
        return ckpt_format.write_agent_checkpoint(
            path, "AsymmetricSACAgent", config, {"loss": self.loss.state_dict()},
            {"optim": self.optim.state_dict()} if optimisers else None, meta)

    @classmethod
    def from_checkpoint(cls, ckpt: dict, path="<checkpoint>",
                        map_location=None) -> AsymmetricSACAgent:
        """An agent from a validated checkpoint dict (see :meth:`load`)."""
        config = ckpt["config"]
        sac_config = ckpt_format.config_from_dict(
            AsymmetricSACConfig, ckpt_format.part(config, path, "sac"), path,
            "AsymmetricSACConfig")
        dims = [ckpt_format.part(config, path, key) for key in ("state_dim", "action_dim")]
        if not all(isinstance(d, int) and not isinstance(d, bool) and d > 0 for d in dims):
            raise ckpt_format.incompatible(path, f"its state/action sizes {dims} are not "
                                           "positive integers")
        agent = cls(*dims, sac_config)
        ckpt_format.load_weights(agent.loss, ckpt_format.part(ckpt["weights"], path, "loss"),
                                 path, "loss")
        ckpt_format.load_optimisers(agent, ckpt, ("optim",), path)
        agent.checkpoint_meta = dict(ckpt.get("meta", {}))
        return agent.to(map_location) if map_location is not None else agent


class AsymmetricSACPolicy(TensorDictModuleBase):
    """The actor with ``SACLoss``'s trained parameters swapped in (the loss owns them).

    With ``frames = k > 1`` it keeps the previous ``k - 1`` images in ``("agent",
    "frames")`` (the env needs :meth:`AsymmetricSACAgent.make_primer`); at an episode's
    first step (``is_init``) the history is the current image repeated.
    """

    def __init__(self, loss: SACLoss, explore: bool, frames: int = 1):
        super().__init__()
        self.loss, self.explore, self.frames = loss, explore, frames
        history = [("agent", "frames")] if frames > 1 else []
        self.in_keys = ["pixels", *(["is_init"] if history else []), *history]
        self.out_keys = ["action", *[("next", *k) for k in history]]

    def _stack(self, td: TensorDictBase) -> TensorDictBase:
        pixels = td.get("pixels")
        history = td.get(("agent", "frames"), None)
        is_init = td.get("is_init", None)
        if history is None or is_init is None:
            raise KeyError(f"a {self.frames}-frame actor needs 'is_init' and ('agent', "
                           "'frames'): build the env with AsymmetricSACAgent.make_primer() "
                           "and torchrl.envs.InitTracker()")
        repeated = pixels.unsqueeze(-4).expand(*pixels.shape[:-3], self.frames - 1,
                                               *pixels.shape[-3:])
        start = is_init.reshape(*pixels.shape[:-3], 1, 1, 1, 1).bool()
        history = torch.where(start, repeated, history.to(pixels.dtype))
        stack = torch.cat([history, pixels.unsqueeze(-4)], -4)
        td.set(("next", "agent", "frames"), stack[..., 1:, :, :, :])
        return td.empty().set("pixels", stack)

    @torch.no_grad()
    def forward(self, td: TensorDictBase) -> TensorDictBase:
        mode = ExplorationType.RANDOM if self.explore else ExplorationType.DETERMINISTIC
        pixels = td.get("pixels")
        check_finite("pixels", pixels)  # a NaN would become a NaN action, silently
        check_pixels(type(self).__name__, "pixels", pixels)  # uint8 or [-0.5, 0.5]
        actor_in = td if self.frames == 1 else self._stack(td)
        # images go to the actor's device and the action comes back to the env's
        home, device = pixels.device, module_device(self.loss)
        if device != home:  # a copy there: the env's tensordict keeps its own device
            actor_in = actor_in.to(device)
        with set_exploration_type(mode), \
                self.loss.actor_network_params.to_module(self.loss.actor_network):
            out = self.loss.actor_network(actor_in)
        return td if out is td else td.set("action", out.get("action").to(home))
