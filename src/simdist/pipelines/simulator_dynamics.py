"""Plan with the simulator as the model: the ceiling of dynamics-only finetuning.

SimDist finetunes only the dynamics; the encoder, reward, value and policy-prior heads stay
as pretrained. The most a perfect finetune could give is therefore the same planner
(:class:`~simdist.modules.LatentMPPIPlanner`, same config, same heads) with the *true*
dynamics of the deployment domain in place of the learned ones. :class:`SimulatorDynamics`
is that model: a candidate's "latent" is ``[world index, MuJoCo state, observation
history]``; stepping it runs MuJoCo on a scratch copy of that world; the heads read the
encoded history. ``experiments/simulator_dynamics_planner.py`` evaluates it.
"""

from __future__ import annotations

import mujoco
import numpy as np
import torch
from tensordict import TensorDict
from torch import nn

from simdist.agents.simdist import PREVIOUS_ACTION, previous_action_of
from simdist.envs.simulation import Simulation
from simdist.modules.planner import LatentMPPIPlanner

_STATE = mujoco.mjtState.mjSTATE_INTEGRATION  # qpos, qvel, act, warm start, ctrl, time


class SimulatorDynamics:
    """``(z, a) -> z'`` where ``z = [world index, MuJoCo state, observation history]``.

    Each evaluated world ``i`` has one scratch copy (same task, target and episode draws);
    a candidate row sets the copy to its state, steps one control step and reads the new
    state and observation back. Rows are stepped one after another (MuJoCo is serial).
    With ``action_dim > 0`` each step of the history is ``[observation, previous action]``
    (a :class:`~simdist.modules.HistoryEncoder` that reads the previous action): the new
    step pairs the new observation with the action just applied.

    Args:
        worlds: the evaluation env's simulations (``SimDistEnv.sims``; read, never stepped
            here). Robot tasks only (they carry the observation the encoder reads).
        history: the encoder's history length.
        obs_dim: the encoder's observation size.
        action_dim: the previous action's size in each history step (0: observations only).

    Examples:
        >>> from simdist.envs import make_env
        >>> env = make_env("quadruped-flat", num_envs=1, seed=0)
        >>> dynamics = SimulatorDynamics(env.sims, history=2, obs_dim=89)
        >>> dynamics.sync()
        >>> z = dynamics.latent(env.reset()["observation"][:, None].expand(1, 2, 89))
        >>> dynamics(z, torch.zeros(1, 12)).shape == z.shape
        True
    """

    def __init__(self, worlds: list[Simulation], history: int, obs_dim: int,
                 action_dim: int = 0):
        if not worlds or not all(w.spec.is_robot for w in worlds):
            raise ValueError("SimulatorDynamics needs the worlds of a robot task (e.g. "
                             "quadruped-flat): the encoder reads their 'observation'")
        first = worlds[0]
        if first.observation_layout.size != obs_dim:
            raise ValueError(f"the worlds' observation has size {first.observation_layout.size}"
                             f", the encoder reads {obs_dim}")
        self.worlds, self.history, self.obs_dim = worlds, history, obs_dim
        self.action_dim, self.step_width = action_dim, obs_dim + action_dim
        self.copies = [Simulation(w.spec, w.target, None, None, False, 8, None, 0,
                                  w.task_kwargs, w.max_episode_steps)
                       for w in worlds]
        self.state_size = mujoco.mj_stateSize(first.physics.model.ptr, _STATE)
        self.row = {"observation": np.zeros(obs_dim), "state": np.zeros(first.state_layout.size),
                    "forward_progress": np.zeros(1), "dynamics": np.zeros(
                        len(first.params.as_array())), "reward": np.zeros(1),
                    "terminated": np.zeros(1, bool), "truncated": np.zeros(1, bool)}
        self.latent_dim = 1 + self.state_size + history * self.step_width

    def sync(self) -> None:
        """Copies each world's episode draws (dynamics, command) into its scratch copy."""
        for world, copy in zip(self.worlds, self.copies):
            if world.params.action_latency:
                raise ValueError(f"target {world.target.name!r} has action latency: the "
                                 "scratch copies do not model the delay line")
            copy.params = world.params
            copy._dyn_editor.apply(world.params)
            copy.task.command = world.task.command
            if world.task.slope_range_deg is not None:  # the incline is drawn per episode
                copy.task._set_slope(world.task.slope_deg)
                floor = world.task._idx["floor"]
                copy.physics.model.geom_quat[floor] = world.physics.model.geom_quat[floor]

    def latent(self, history: torch.Tensor) -> torch.Tensor:
        """``[B, latent_dim]`` from the worlds' current states and histories ``[B, T, W]``
        (``W``: observation, then previous action if ``action_dim``)."""
        rows = []
        for i, world in enumerate(self.worlds):
            state = np.empty(self.state_size)
            mujoco.mj_getState(world.physics.model.ptr, world.physics.data.ptr, state, _STATE)
            rows.append(np.concatenate([[i], state]))
        head = torch.as_tensor(np.stack(rows), dtype=torch.float64)
        return torch.cat([head, history.reshape(len(rows), -1).double()], 1)

    def history_of(self, z: torch.Tensor) -> torch.Tensor:
        """The histories ``[N, T, W]`` (float32) inside latents ``z``."""
        return z[:, 1 + self.state_size:].float().reshape(-1, self.history, self.step_width)

    def __call__(self, z: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        out = z.clone()
        states, actions = z[:, 1:1 + self.state_size].numpy(), a.double().numpy()
        obs = np.empty((len(z), self.obs_dim))
        for r, (index, state, action) in enumerate(zip(z[:, 0].long().tolist(), states, actions)):
            copy = self.copies[index]
            m, d = copy.physics.model.ptr, copy.physics.data.ptr
            mujoco.mj_setState(m, d, state, _STATE)
            # dm_control's step finishes a step begun by mj_step1 (positions, velocities,
            # sensors of the current state): redo that part for the state just set.
            mujoco.mj_step1(m, d)
            copy.step(action, self.row)
            mujoco.mj_getState(m, d, out[r, 1:1 + self.state_size].numpy(), _STATE)
            obs[r] = self.row["observation"]
        step = torch.as_tensor(obs).float()
        if self.action_dim:  # the new observation's previous action: the one just applied
            step = torch.cat([step, a.float()], -1)
        history = torch.cat([self.history_of(z)[:, 1:], step[:, None]], 1)
        out[:, 1 + self.state_size:] = history.reshape(len(z), -1).double()
        return out


class SimulatorPlanningPolicy(nn.Module):
    """A SimDist agent's planner and heads with :class:`SimulatorDynamics` as the model.

    Keeps the history window exactly as :class:`~simdist.agents.SimDistPolicy` does
    (``("simdist", "history")``, and ``("simdist", "previous_action")`` for an encoder that
    reads it, from ``agent.make_primer(0)``); the reward, terminal value
    and prior proposals are the agent's heads on the encoded history of each candidate.

    Args:
        agent: a :class:`~simdist.agents.SimDistAgent` (only its heads are used).
        worlds: the env's simulations (``env.base_env.sims``), one per batch row.
        planner_config: the :class:`~simdist.modules.PlannerConfig` to plan with.
        action_low: per-dimension action bounds (the env's action spec).
        action_high: per-dimension action bounds.
        seed: seed of the planner's sampling noise.

    Examples:
        >>> from torchrl.envs import InitTracker, TransformedEnv
        >>> from simdist.agents import SimDistAgent
        >>> from simdist.envs import make_env
        >>> from simdist.modules import PlannerConfig, SimDistWorldModel
        >>> agent = SimDistAgent(SimDistWorldModel.build(89, 12, size="tiny", history=2))
        >>> env = TransformedEnv(make_env("quadruped-flat", num_envs=1, seed=0), InitTracker())
        >>> env = env.append_transform(agent.make_primer(0))
        >>> policy = SimulatorPlanningPolicy(agent, env.base_env.sims, PlannerConfig(
        ...     horizon=2, num_samples=4, num_elites=2, iterations=1), -torch.ones(12),
        ...     torch.ones(12), seed=0)
        >>> env.rollout(2, policy)["action"].shape
        torch.Size([1, 2, 12])
    """

    def __init__(self, agent, worlds, planner_config, action_low, action_high, seed: int):
        super().__init__()
        model = agent.world_model
        enc = model.encoder
        self.model, self.enc = model, enc
        self.dynamics = SimulatorDynamics(worlds, enc.history, enc.obs_dim, enc.action_dim)

        def encoded(z):
            # Any leading shape: the lambda-return reads the values of several predicted
            # steps at once ([steps, candidates, latent]).
            flat = self.dynamics.history_of(z.reshape(-1, z.shape[-1]))
            return model.encode(flat).reshape(*z.shape[:-1], -1)

        # The heads run in float32; the simulator state rides in float64.
        self.planner = LatentMPPIPlanner(
            dynamics=self.dynamics,
            reward=lambda z, a: model.reward(encoded(z), a.float()).double(),
            value=lambda z: model.value(encoded(z)).double(),
            policy=lambda z: model.policy(encoded(z)).double(),
            action_dim=model.action_dim, config=planner_config, seed=seed,
            action_bounds=(action_low, action_high), latent_dim=self.dynamics.latent_dim)
        self.planner.action_low = self.planner.action_low.double()
        self.planner.action_high = self.planner.action_high.double()

    @torch.no_grad()
    def forward(self, td):
        obs, enc = td["observation"], self.enc
        is_init = td["is_init"].reshape(-1, 1).bool()
        history = enc.push(td.get(("simdist", "history"), None), obs,
                           previous_action_of(td, enc), is_init)
        if is_init.any():  # new episodes: new draws (commands, dynamics) to copy
            self.dynamics.sync()
        plan = self.planner(TensorDict({"latent": self.dynamics.latent(history),
                                        "is_init": is_init}, [obs.shape[0]]))
        td.set("action", plan["action"].float())
        if enc.action_dim:
            td.set(("next", *PREVIOUS_ACTION), td.get("action").clone())
        td.set(("next", "simdist", "history"), history)
        td.set(("planner", "rewards"), plan["planner", "rewards"].float())
        return td
