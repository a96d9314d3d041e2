"""The TorchRL environment: privileged state, robot observation and pixels in one TensorDict."""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from simdist.envs.layout import Layout
from simdist.envs.randomisation import DynamicsParams, DynamicsRandomisation, VisualRandomisation
from simdist.envs.simulation import Simulation
from simdist.envs.targets import TargetDomain, get_target
from simdist.envs.tasks import get_task


class SimDistEnv(EnvBase):
    """A batch of dm_control worlds as one TorchRL environment.

    Every reading of a step comes from the same physics state: ``"state"`` (privileged,
    float32, layout in :attr:`state_layout`), ``"observation"`` for robots (what the robot
    can measure: proprioception + height scan, layout in :attr:`observation_layout`),
    ``"pixels"`` (uint8 ``(H, W, 3)``) when asked, ``"dynamics"`` (the episode's
    :class:`DynamicsParams` as a vector: privileged, for asymmetric critics) and, for
    locomotion, ``"forward_progress"`` (metres along the direction of travel since reset).

    ``num_envs=None`` gives an unbatched env (``batch_size=()``); an integer steps that
    many worlds in one process (``batch_size=(num_envs,)``), amortising TorchRL's per-call
    overhead; partial resets through ``"_reset"`` are supported. Use TorchRL's
    ``ParallelEnv`` to spread worlds over processes.

    Args:
        task: a name from :data:`simdist.envs.TASKS`.
        num_envs: worlds stepped in this process, or ``None`` for an unbatched env.
        pixels: render pixels each step.
        image_size: square render size.
        camera_id: render camera (default: the task's).
        dynamics_randomisation: per-episode dynamics ranges, or ``None``.
        visual_randomisation: visual DR (needs ``pixels=True``), or ``None``.
        target: a target-domain preset name, a :class:`TargetDomain`, or a dict of its
            fields (e.g. ``{"friction": 0.3}``) (default: sim).
        seed: seeds every random draw; equal seeds give identical rollouts.
        task_kwargs: task options (quadruped: ``speeds``, ``slope_deg``).
        max_episode_steps: truncation length in agent steps (default: the task's).
        device: device of the returned tensors.

    Examples:
        >>> env = SimDistEnv("cartpole-balance", seed=0)
        >>> td = env.rollout(3)
        >>> td["next", "state"].shape
        torch.Size([3, 5])
        >>> env.state_layout.names()
        ['position', 'velocity']
    """

    def __init__(self, task: str, *, num_envs: int | None = None, pixels: bool = False,
                 image_size: int = 64, camera_id: int | None = None,
                 dynamics_randomisation: DynamicsRandomisation | None = None,
                 visual_randomisation: VisualRandomisation | None = None,
                 target: str | TargetDomain | dict | None = None, seed: int = 0,
                 task_kwargs: dict | None = None, max_episode_steps: int | None = None,
                 device: str | torch.device = "cpu"):
        spec = get_task(task)
        target = get_target(target)
        if num_envs is not None and num_envs < 1:
            raise ValueError(f"num_envs must be >= 1 or None, got {num_envs}")
        if image_size < 8:
            raise ValueError(f"image_size must be >= 8, got {image_size}")
        if (visual_randomisation is not None or target.visual is not None) and not pixels:
            raise ValueError("visual randomisation only affects pixels: pass pixels=True")
        n = 1 if num_envs is None else int(num_envs)
        super().__init__(device=device, batch_size=() if num_envs is None else (n,))
        self.task_spec, self.target, self.pixels = spec, target, pixels
        self.sims = [
            Simulation(spec, target, dynamics_randomisation, visual_randomisation, pixels,
                       image_size, camera_id, s, task_kwargs, max_episode_steps)
            for s in self._seeds(seed, n)
        ]
        self._batched = num_envs is not None
        sim = self.sims[0]
        self.state_layout: Layout = sim.state_layout
        self.observation_layout: Layout | None = sim.observation_layout
        self._buffers = self._make_buffers(n, sim, image_size)
        self._rows = [{k: v[i] for k, v in self._buffers.items()} for i in range(n)]
        self._obs_keys = [k for k in self._buffers if k not in ("reward", "terminated", "truncated")]
        self._make_specs(sim, image_size)

    # -- construction helpers ---------------------------------------------------------
    @staticmethod
    def _seeds(seed: int, n: int) -> list[int]:
        return [int(s) for s in np.random.SeedSequence(int(seed)).generate_state(n)]

    def _make_buffers(self, n: int, sim: Simulation, image_size: int) -> dict:
        shapes = {"state": ((sim.state_layout.size,), np.float32),
                  "dynamics": ((len(DynamicsParams.FIELDS),), np.float32)}
        if sim.observation_layout is not None:
            shapes["observation"] = ((sim.observation_layout.size,), np.float32)
        for name in sim.readings:  # forward_progress (locomotion), success (manipulation)
            shapes[name] = ((1,), np.float32)
        if self.pixels:
            shapes["pixels"] = ((image_size, image_size, 3), np.uint8)
        shapes.update(reward=((1,), np.float32), terminated=((1,), bool), truncated=((1,), bool))
        return {k: np.zeros((n, *shape), dtype) for k, (shape, dtype) in shapes.items()}

    def _make_specs(self, sim: Simulation, image_size: int) -> None:
        b = self.batch_size
        obs = {}
        for key in self._obs_keys:
            shape = b + self._buffers[key].shape[1:]
            if key == "pixels":
                obs[key] = Bounded(0, 255, shape, dtype=torch.uint8, device=self.device)
            else:
                obs[key] = Unbounded(shape, dtype=torch.float32, device=self.device)
        self.observation_spec = Composite(obs, shape=b, device=self.device)
        low, high = torch.as_tensor(sim.action_low), torch.as_tensor(sim.action_high)
        if torch.isfinite(low).all() and torch.isfinite(high).all():
            self.action_spec = Bounded(low.expand(b + low.shape), high.expand(b + high.shape),
                                       b + low.shape, dtype=torch.float32, device=self.device)
        else:
            self.action_spec = Unbounded(b + low.shape, dtype=torch.float32, device=self.device)
        self.reward_spec = Unbounded(b + (1,), dtype=torch.float32, device=self.device)
        self.done_spec = Composite(
            {k: Categorical(2, b + (1,), dtype=torch.bool, device=self.device)
             for k in ("done", "terminated", "truncated")}, shape=b, device=self.device)

    # -- TorchRL hooks ----------------------------------------------------------------
    def _output(self, keys) -> TensorDict:
        out = {}
        for key in keys:
            arr = self._buffers[key] if self._batched else self._buffers[key][0]
            out[key] = torch.from_numpy(arr.copy())
        done = out["terminated"] | out["truncated"]
        out["done"] = done
        # Shapes and dtypes come from our own buffers: skip TensorDict's validation.
        return TensorDict._new_unsafe(out, batch_size=self.batch_size, device=self.device)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        mask = None
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = tensordict.get("_reset").reshape(-1).cpu().numpy()
        for i, sim in enumerate(self.sims):
            if mask is None or mask[i]:
                sim.reset(self._rows[i])
            else:  # untouched worlds report their current readings, not-done
                self._rows[i]["terminated"][0] = self._rows[i]["truncated"][0] = False
        return self._output(self._obs_keys + ["terminated", "truncated"])

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get("action")
        actions = action.detach().cpu().numpy().reshape(len(self.sims), -1)
        if not np.isfinite(actions).all():
            raise ValueError(f"{self.task_spec.name}: non-finite value in 'action': {action}")
        for sim, act, row in zip(self.sims, actions, self._rows):
            sim.step(act, row)
        return self._output(self._obs_keys + ["reward", "terminated", "truncated"])

    def _set_seed(self, seed: int | None) -> None:
        if seed is None:
            return
        for sim, s in zip(self.sims, self._seeds(seed, len(self.sims))):
            sim.seed(s)

    # -- conveniences -----------------------------------------------------------------
    def render(self, index: int = 0, size: int | None = None,
               camera_id: int | None = None) -> np.ndarray:
        """Renders world ``index`` now (e.g. a large frame for a video)."""
        return self.sims[index].render(size, camera_id)
