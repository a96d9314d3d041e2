"""Train a state-based expert with TorchRL SAC under dynamics randomisation.

SAC is the sample-efficient choice on 2 CPU cores (PPO needs thousands of parallel envs
to shine). The critic is kept: ``Q(s, pi(s))`` labels dataset values. Checkpoints are
written atomically every ``checkpoint_every`` frames (resume picks up the latest), and a
snapshot of the actor is kept at each of ``snapshot_every`` frames: earlier, weaker
policies make the SimDist dataset mixed-quality.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.objectives import SACLoss, SoftUpdate
from tqdm import tqdm

from simdist.envs import DynamicsRandomisation, get_target, make_env
from simdist.envs.manipulation import TASK_CLASSES as TABLETOP_TASKS
from simdist.experts.networks import make_actor, make_critic
from simdist.modules.checks import check_finite
from simdist.utils.atomic import write_json_atomic
from simdist.utils.checkpoint import CorruptCheckpointError, load_checkpoint, save_atomic


@dataclass
class SACExpertConfig:
    """Expert training configuration (flat, typed; saved beside every checkpoint).

    ``init_from`` names an ``expert.pt`` whose actor and critic start the run (the
    committed terrain expert continues the flat-ground expert this way); pair it with a
    small ``alpha_init``, or SAC's entropy bonus first undoes what the actor knows.

    Examples:
        >>> cfg = SACExpertConfig(num_envs=4, frames_per_batch=32)
        >>> dataclasses.asdict(cfg)["task"], cfg.frames_per_batch // cfg.num_envs
        ('quadruped-flat', 8)
        >>> SACExpertConfig(num_envs=3, frames_per_batch=64)
        Traceback (most recent call last):
        ...
        ValueError: frames_per_batch must be a multiple of num_envs
    """

    task: str = "quadruped-flat"
    speeds: tuple = (0.25, 0.5, 0.75)  # quadruped tasks: commanded speeds
    init: str = "narrow"  # manipulation tasks: the initial-condition grid (narrow, wide)
    num_envs: int = 8
    total_frames: int = 400_000
    init_random_frames: int = 10_000
    frames_per_batch: int = 64
    updates_per_batch: int = 32
    batch_size: int = 256
    buffer_size: int = 1_000_000
    lr: float = 3e-4
    gamma: float = 0.99
    tau: float = 0.005
    hidden: int = 256
    episode_steps: int = 500
    dynamics_randomisation: bool = True
    checkpoint_every: int = 20_000
    snapshot_every: int = 50_000
    eval_episodes: int = 4
    alpha_init: float = 1.0
    init_from: str | None = None
    # train *in* a named target domain (its fixed dynamics and slope, no randomisation):
    # an online oracle that measures what a policy can reach there, not a deployable expert
    target: str | None = None
    seed: int = 0

    def __post_init__(self):
        for name in ("num_envs", "total_frames", "frames_per_batch", "batch_size"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1")
        if self.frames_per_batch % self.num_envs:
            raise ValueError("frames_per_batch must be a multiple of num_envs")
        if not self.alpha_init > 0:
            raise ValueError(f"alpha_init must be > 0, got {self.alpha_init}")
        if self.target is not None:
            get_target(self.target)  # an unknown name fails here, naming the valid ones


def task_kwargs(cfg: SACExpertConfig) -> dict:
    """The task options the config sets: speeds for locomotion, the grid for manipulation."""
    if cfg.task in TABLETOP_TASKS:
        return {"init": cfg.init}
    if cfg.task.startswith("quadruped"):
        return {"speeds": tuple(cfg.speeds)}
    return {}


def make_training_env(cfg: SACExpertConfig, seed: int, num_envs: int | None = None, target=None):
    target = cfg.target if target is None else target
    return make_env(cfg.task, num_envs=num_envs if num_envs is not None else cfg.num_envs,
                    seed=seed, max_episode_steps=cfg.episode_steps, target=target,
                    task_kwargs=task_kwargs(cfg),
                    dynamics_randomisation=DynamicsRandomisation()
                    if cfg.dynamics_randomisation and target is None else None)


class Expert:
    """A trained expert: deterministic policy and value labels ``V(s) = Q(s, pi(s))``.

    Examples:
        >>> expert = Expert.untrained(obs_dim=89, action_dim=12)
        >>> td = TensorDict({"observation": torch.zeros(3, 89)}, [3])
        >>> expert.act(td)["action"].shape, expert.value(td).shape
        (torch.Size([3, 12]), torch.Size([3, 1]))
    """

    def __init__(self, actor, critic):
        self.actor, self.critic = actor, critic
        self.checkpoint_meta: dict = {}  # Expert.load: the task it was trained on
        net = actor.module[0]  # TensorDictModule: observation -> (loc, scale)
        spec = actor.spec["action"] if "action" in actor.spec.keys() else actor.spec
        self._net = net.module
        self._low, self._high = spec.space.low, spec.space.high

    def deterministic(self) -> TensorDictModule:
        """The deterministic policy as a plain ``TensorDictModule`` (no distribution).

        Same actions as ``act(td)`` (TanhNormal's deterministic sample: the location
        squashed by tanh into the action bounds) at a fraction of the per-call cost,
        which matters when generating millions of transitions.
        """
        low, high, net = self._low, self._high, self._net

        def act(observation):
            check_finite("observation", observation)  # else a NaN action, silently
            loc, _ = net(observation)
            return low + (high - low) * (torch.tanh(loc) + 1) / 2

        return TensorDictModule(act, in_keys=["observation"], out_keys=["action"])

    def policy(self, explore: bool = False, action_spec=None) -> TensorDictModule:
        """The agents' interface (``simdist.pipelines.evaluate_agent``): the deterministic
        policy (an expert acts deterministically; ``explore`` must be False)."""
        if explore:
            raise ValueError("an Expert's policy is deterministic; sample with act(td, False)")
        return self.deterministic()

    def make_primer(self) -> None:
        """An expert is memoryless: no recurrent state to prime (agents' interface)."""
        return None

    def to(self, device) -> Expert:
        """Moves the networks (and action bounds) to ``device``; returns ``self``."""
        self.actor, self.critic = self.actor.to(device), self.critic.to(device)
        self._low, self._high = self._low.to(device), self._high.to(device)
        return self

    @classmethod
    def untrained(cls, obs_dim: int, action_dim: int, hidden: int = 256) -> Expert:
        from torchrl.data import Bounded
        spec = Bounded(-1.0, 1.0, (action_dim,))
        return cls(make_actor(obs_dim, spec, hidden), make_critic(obs_dim, action_dim, hidden))

    @torch.no_grad()
    def act(self, td: TensorDict, deterministic: bool = True) -> TensorDict:
        mode = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
        with set_exploration_type(mode):
            return self.actor(td)

    @torch.no_grad()
    def value(self, td: TensorDict) -> torch.Tensor:
        probe = self.act(td.select("observation").clone())
        return self.critic(probe)["state_action_value"]

    def save(self, path: str | Path, obs_dim: int, config: SACExpertConfig, snapshots=None,
             curve=(), frames: int = 0) -> Path:
        """Writes a weights-only ``expert.pt`` that :meth:`load` reads back."""
        path = Path(path)
        save_atomic({
            "actor": {k: v.detach().clone() for k, v in self.actor.state_dict().items()},
            "critic": {k: v.detach().clone() for k, v in self.critic.state_dict().items()},
            "snapshots": dict(snapshots or {}), "curve": list(curve), "frames": frames,
            "obs_dim": obs_dim, "action_low": self._low.clone(), "action_high": self._high.clone(),
            "config": dataclasses.asdict(config)}, path)
        return path

    #: What :meth:`save` writes and :meth:`load` needs.
    REQUIRED_KEYS = ("actor", "critic", "obs_dim", "action_low", "action_high", "config")
    _RECOVERY = ("retrain it (python recipes/train_expert.py, or train_sac_expert) or pass "
                 "the path of a good expert.pt")

    @classmethod
    def load(cls, path: str | Path, snapshot: str | None = None) -> Expert:
        """Loads ``expert.pt`` (the final policy, or a named earlier ``snapshot``).

        Raises:
            CorruptCheckpointError: the file is corrupt, lacks one of
                :attr:`REQUIRED_KEYS`, or its weights do not fit the networks it describes.
            KeyError: no such ``snapshot``.
        """
        ckpt = load_checkpoint(path, recovery=cls._RECOVERY)

        def incompatible(why: str) -> CorruptCheckpointError:
            return CorruptCheckpointError(f"expert {str(path)!r} is corrupt or incompatible: "
                                          f"{why}. To recover, {cls._RECOVERY}")

        if not isinstance(ckpt, dict):
            raise incompatible(f"it holds a {type(ckpt).__name__}, not an expert's dict")
        missing = [k for k in cls.REQUIRED_KEYS if k not in ckpt]
        if missing:
            raise incompatible(f"it lacks {missing} (has {sorted(map(str, ckpt))}); is it a "
                               "training checkpoint (latest.pt) rather than expert.pt?")
        cfg, spec_low, spec_high = ckpt["config"], ckpt["action_low"], ckpt["action_high"]
        if not (isinstance(cfg, dict) and "hidden" in cfg):
            raise incompatible("its 'config' has no 'hidden' size")
        if not (isinstance(spec_low, torch.Tensor) and isinstance(spec_high, torch.Tensor)
                and spec_low.shape == spec_high.shape and spec_low.dim() == 1):
            raise incompatible("'action_low'/'action_high' are not two equal 1-d tensors")
        snapshots = ckpt.get("snapshots", {})
        if snapshot is not None and snapshot not in snapshots:
            raise KeyError(f"no snapshot {snapshot!r}; available: {sorted(snapshots)}")
        from torchrl.data import Bounded
        spec = Bounded(spec_low, spec_high, spec_low.shape)
        actor = make_actor(ckpt["obs_dim"], spec, cfg["hidden"])
        critic = make_critic(ckpt["obs_dim"], spec_low.shape[-1], cfg["hidden"])
        try:
            actor.load_state_dict(snapshots[snapshot] if snapshot else ckpt["actor"])
            critic.load_state_dict(ckpt["critic"])
        except (RuntimeError, TypeError, AttributeError) as err:  # wrong or mis-shaped weights
            raise incompatible(f"its weights do not fit the networks it describes "
                               f"({str(err).splitlines()[0]})") from None
        expert = cls(actor.eval(), critic.eval())
        expert.checkpoint_meta = {"task": cfg.get("task", ""), "frames": ckpt.get("frames", 0)}
        return expert


def evaluate(actor, cfg: SACExpertConfig, episodes: int, seed: int, target=None) -> dict:
    """Deterministic rollouts: mean return, and the task's readings at the last step
    (``forward_progress`` in metres for locomotion, the ``success`` rate for manipulation)."""
    env = make_training_env(cfg, seed, num_envs=episodes, target=target)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        td = env.rollout(cfg.episode_steps, actor, break_when_any_done=False)
    out = {"return": td["next", "reward"].sum(-2).mean().item()}
    for name in env.sims[0].readings:
        out[name] = td["next", name][:, -1].mean().item()
    return out


def describe_metrics(metrics: dict) -> dict:
    """A progress bar's postfix: the return and the task's reading."""
    shown = {"ret": f"{metrics['return']:.0f}"}
    if "forward_progress" in metrics:
        shown["progress"] = f"{metrics['forward_progress']:.2f}m"
    if "success" in metrics:
        shown["success"] = f"{metrics['success']:.0%}"
    return shown


def train_sac_expert(cfg: SACExpertConfig, out_dir: str | Path, progress: bool = True) -> Path:
    """Trains (or resumes) an expert; returns the path of ``expert.pt``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(cfg.seed)
    env = make_training_env(cfg, cfg.seed)
    obs_dim = env.observation_spec["observation"].shape[-1]
    action_spec = env.action_spec[0] if env.batch_size else env.action_spec
    actor = make_actor(obs_dim, action_spec, cfg.hidden)
    critic = make_critic(obs_dim, action_spec.shape[-1], cfg.hidden)
    with torch.no_grad():  # materialise lazy shapes
        td = env.reset()
        critic(actor(td))
    if cfg.init_from is not None:
        start = Expert.load(cfg.init_from)
        if start._low.shape != action_spec.space.low.shape:
            raise ValueError(f"init_from={cfg.init_from!r} was trained for another action space")
        actor.load_state_dict(start.actor.state_dict())
        critic.load_state_dict(start.critic.state_dict())
    loss = SACLoss(actor, critic, num_qvalue_nets=2, loss_function="l2",
                   alpha_init=cfg.alpha_init)
    loss.make_value_estimator(gamma=cfg.gamma)
    updater = SoftUpdate(loss, tau=cfg.tau)
    if cfg.init_from is not None:
        # SACLoss re-initialises each of its Q copies (and their targets) so that they
        # differ; a warm start must put the loaded critic back into every one of them.
        loaded = TensorDict.from_module(critic).data.expand(2)
        loss.qvalue_network_params.data.update_(loaded)
        loss.target_qvalue_network_params.data.update_(loaded)
    optim = torch.optim.Adam(loss.parameters(), lr=cfg.lr)
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(cfg.buffer_size),
                                    batch_size=cfg.batch_size)
    latest = out_dir / "latest.pt"
    state = {"frames": 0, "snapshots": {}, "curve": []}
    if latest.exists():  # resume: weights and counters (the replay buffer is refilled)
        ckpt = load_checkpoint(latest)
        loss.load_state_dict(ckpt["loss"])
        optim.load_state_dict(ckpt["optim"])
        state = {"frames": ckpt["frames"], "snapshots": ckpt["snapshots"], "curve": ckpt["curve"]}
    remaining = cfg.total_frames - state["frames"]
    if remaining <= 0:
        return _export(out_dir, cfg, loss, state, obs_dim, action_spec)
    # A warm start collects its first ``init_random_frames`` with its own policy: random
    # actions would only fill the buffer with falls the policy no longer makes.
    random_frames = 0 if cfg.init_from else max(0, cfg.init_random_frames - state["frames"])
    collector = Collector(env, actor, frames_per_batch=cfg.frames_per_batch,
                          total_frames=remaining, init_random_frames=random_frames or None,
                          auto_register_policy_transforms=False)
    bar = tqdm(total=cfg.total_frames, initial=state["frames"], disable=not progress,
               desc="SAC expert", unit="frames")
    start, last_ckpt = time.perf_counter(), state["frames"]
    for batch in collector:
        buffer.extend(batch.reshape(-1))
        state["frames"] += batch.numel()
        bar.update(batch.numel())
        if len(buffer) >= cfg.batch_size and state["frames"] >= cfg.init_random_frames:
            for _ in range(cfg.updates_per_batch):
                out = loss(buffer.sample())
                total = out["loss_actor"] + out["loss_qvalue"] + out["loss_alpha"]
                optim.zero_grad()
                total.backward()
                optim.step()
                updater.step()
        if state["frames"] - last_ckpt >= cfg.checkpoint_every or state["frames"] >= cfg.total_frames:
            last_ckpt = state["frames"]
            # SACLoss owns the trained parameters: evaluate with them swapped in.
            with loss.actor_network_params.to_module(loss.actor_network):
                metrics = evaluate(loss.actor_network, cfg, cfg.eval_episodes, seed=10_000)
            metrics.update(frames=state["frames"], seconds=time.perf_counter() - start)
            state["curve"].append(metrics)
            bar.set_postfix(**describe_metrics(metrics))
            due = (len(state["snapshots"]) + 1) * cfg.snapshot_every
            if due <= state["frames"] < cfg.total_frames:
                state["snapshots"][f"frames_{state['frames']}"] = _actor_state(loss)
            save_atomic({"loss": loss.state_dict(), "optim": optim.state_dict(), **state,
                         "config": dataclasses.asdict(cfg)}, latest)
    collector.shutdown()
    bar.close()
    return _export(out_dir, cfg, loss, state, obs_dim, action_spec)


def _export(out_dir, cfg, loss, state, obs_dim, action_spec) -> Path:
    """Writes the small deployable ``expert.pt`` (actor, critic, snapshots, curve)."""
    actor = make_actor(obs_dim, action_spec, cfg.hidden)
    critic = make_critic(obs_dim, action_spec.shape[-1], cfg.hidden)
    actor.load_state_dict(_actor_state(loss))
    critic.load_state_dict(_critic_state(loss))
    path = Expert(actor, critic).save(out_dir / "expert.pt", obs_dim, cfg, state["snapshots"],
                                      state["curve"], state["frames"])
    write_json_atomic(out_dir / "training_curve.json", state["curve"])
    return path


def _actor_state(loss: SACLoss) -> dict:
    # SACLoss holds functional copies of the parameters; write them back into a module.
    actor = loss.actor_network
    with loss.actor_network_params.to_module(actor):
        return {k: v.detach().clone() for k, v in actor.state_dict().items()}


def _critic_state(loss: SACLoss) -> dict:
    critic = loss.qvalue_network
    with loss.qvalue_network_params[0].to_module(critic):
        return {k: v.detach().clone() for k, v in critic.state_dict().items()}
