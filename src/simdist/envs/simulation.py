"""One simulated world: dm_control physics + task + randomisers, stepped without wrappers.

:class:`Simulation` drives the dm_control task exactly as ``control.Environment`` does
(``before_step`` / ``physics.step`` / ``after_step``) but writes readings straight into
caller-owned numpy rows, so a batch of simulations fills one array per key with no
per-step dict building. Everything that makes a rollout random (task initial states,
randomisation draws) comes from generators reseeded by :meth:`seed`, so a seed
reproduces a rollout exactly.
"""

from __future__ import annotations

import contextlib
from collections import deque

import numpy as np
from dm_control.rl import control

from simdist.envs import tasks as task_registry
from simdist.envs.model_editing import DynamicsEditor, VisualEditor
from simdist.envs.randomisation import DynamicsParams, DynamicsRandomisation, VisualRandomisation
from simdist.rendering import rendering_error
from simdist.envs.targets import TargetDomain

#: Scalar readings a task may offer (as methods of the task taking the physics).
READINGS = ("forward_progress", "success")


class Simulation:
    """A single dm_control world with dynamics/visual randomisation and a target shift.

    Args:
        spec: the task.
        target: the fixed domain shift.
        dynamics: per-episode dynamics randomisation, or ``None``.
        visual: visual randomisation (overridden by ``target.visual`` when that is set).
        pixels: render ``(image_size, image_size, 3)`` uint8 frames.
        image_size: square render size.
        camera_id: render camera (default: the task's).
        seed: seed for every random draw.
        task_kwargs: forwarded to the task builder (e.g. quadruped ``speeds``).
        max_episode_steps: truncation length (default: the task's).

    Examples:
        >>> from simdist.envs import get_task
        >>> sim = Simulation(get_task("cartpole-balance"), TargetDomain(), dynamics=None,
        ...                  visual=None, pixels=False, image_size=64, camera_id=None, seed=0,
        ...                  max_episode_steps=2)
        >>> row = {k: np.zeros(n) for k, n in [("state", sim.state_layout.size), ("reward", 1),
        ...        ("dynamics", len(DynamicsParams.FIELDS)), ("terminated", 1), ("truncated", 1)]}
        >>> sim.reset(row); sim.step(np.zeros(1), row); sim.step(np.zeros(1), row)
        >>> sim.state_layout.names(), sim.steps, bool(row["truncated"][0])
        (['position', 'velocity'], 2, True)
    """

    def __init__(self, spec: task_registry.TaskSpec, target: TargetDomain,
                 dynamics: DynamicsRandomisation | None, visual: VisualRandomisation | None,
                 pixels: bool, image_size: int, camera_id: int | None, seed: int,
                 task_kwargs: dict | None = None, max_episode_steps: int | None = None):
        if target.slope_deg and not spec.supports_slope:
            raise ValueError(f"target {target.name!r} sets slope_deg={target.slope_deg} but task "
                             f"{spec.name!r} has no slope; slopes exist for quadruped tasks")
        self.spec, self.target, self.dynamics = spec, target, dynamics
        self.max_episode_steps = int(max_episode_steps or spec.max_episode_steps)
        if self.max_episode_steps < 1:
            raise ValueError(f"max_episode_steps must be >= 1, got {max_episode_steps}")
        self.pixels, self.image_size = pixels, int(image_size)
        self.camera_id = spec.camera_id if camera_id is None else int(camera_id)
        self.task_kwargs = dict(task_kwargs or {})  # so a scratch copy can be built alike
        kwargs = {**spec.defaults, **self.task_kwargs}
        self.physics, self.task, self.n_sub_steps = spec.build(target, seed, **kwargs)
        n_cameras = self.physics.model.ncam
        if pixels and not -1 <= self.camera_id < n_cameras:  # -1: MuJoCo's free camera
            raise ValueError(f"camera_id {self.camera_id} does not exist in {spec.name!r}, "
                             f"whose model has {n_cameras} cameras (0..{n_cameras - 1}; "
                             f"-1 is the free camera)")
        self._dyn_editor = DynamicsEditor(self.physics.model.ptr)
        visual = target.visual or visual
        self._vis_editor = VisualEditor(self.physics, visual, self.camera_id) \
            if (visual is not None and pixels) else None
        self.visual = visual
        self.params = target.dynamics()
        if hasattr(self.task, "action_bounds"):  # e.g. Cartesian deltas, not actuator targets
            low, high = self.task.action_bounds(self.physics)
            self.action_low, self.action_high = (np.asarray(low, np.float32),
                                                 np.asarray(high, np.float32))
        else:
            self.action_low = self.physics.model.actuator_ctrlrange[:, 0].astype(np.float32)
            self.action_high = self.physics.model.actuator_ctrlrange[:, 1].astype(np.float32)
            limited = self.physics.model.actuator_ctrllimited.astype(bool)
            self.action_low[~limited], self.action_high[~limited] = -np.inf, np.inf
        #: per-step scalar readings the task offers (locomotion's forward progress, a
        #: manipulation task's success), each an entry of the env's output
        self.readings = tuple(name for name in READINGS if hasattr(self.task, name))
        self.seed(seed)
        # Layouts need an initialised episode (suite observations read the live state).
        self._initialise_episode()
        if spec.is_robot:
            self.state_layout = self.task.state_layout(self.physics)
            self.observation_layout = self.task.observation_layout(self.physics)
        else:
            self.state_layout = task_registry.suite_state_layout(self.task, self.physics)
            self.observation_layout = None
        self.seed(seed)
        self.steps = 0

    @property
    def control_rate(self) -> float:
        """Agent steps per simulated second (a video's real-time frame rate).

        Examples:
            >>> from simdist.envs import get_task
            >>> sim = Simulation(get_task("quadruped-flat"), TargetDomain(), dynamics=None,
            ...                  visual=None, pixels=False, image_size=64, camera_id=None,
            ...                  seed=0)
            >>> sim.control_rate
            50.0
        """
        dt = self.physics.timestep() * self.n_sub_steps * self.spec.action_repeat
        return round(1.0 / dt, 3)

    def seed(self, seed: int) -> None:
        """Reseeds the task's initial-state draws and every randomisation draw."""
        seq = np.random.SeedSequence(int(seed))
        task_seed, dr_seed, vis_seed = seq.spawn(3)
        self.task._random = np.random.RandomState(task_seed.generate_state(1)[0])
        self._dr_rng = np.random.default_rng(dr_seed)
        self._vis_rng = np.random.default_rng(vis_seed)

    # -- episode control --------------------------------------------------------------
    def _initialise_episode(self) -> None:
        draw = self.dynamics.sample(self._dr_rng) if self.dynamics else DynamicsParams()
        self.params = draw.compose(self.target.dynamics())
        self._dyn_editor.apply(self.params)
        self._params_array = self.params.as_array()
        self._pending = deque([np.zeros(len(self.action_low))] * self.params.action_latency)
        with self.physics.reset_context():
            self.task.initialize_episode(self.physics)
        if self._vis_editor is not None:
            self._vis_editor.randomise(self._vis_rng)

    def reset(self, row: dict) -> None:
        """Starts an episode and writes the first readings into ``row``'s arrays."""
        self._initialise_episode()
        self.steps = 0
        self._read(row)
        row["reward"][0] = 0.0

    def step(self, action: np.ndarray, row: dict) -> None:
        """Applies ``action`` (after any latency) and writes readings into ``row``."""
        if self._pending:
            self._pending.append(action)
            action = self._pending.popleft()
        reward, discount = 0.0, None
        for _ in range(self.spec.action_repeat):
            self.task.before_step(action, self.physics)
            try:
                self.physics.step(self.n_sub_steps)
            except control.PhysicsError as err:
                raise RuntimeError(
                    f"{self.spec.name}: MuJoCo became unstable ({err}) with dynamics "
                    f"{self.params}; the target or randomisation ranges may be too extreme"
                ) from err
            self.task.after_step(self.physics)
            reward += self.task.get_reward(self.physics)
            discount = self.task.get_termination(self.physics)
            if discount is not None:
                break
        self.steps += 1
        if self._vis_editor is not None and self.visual.every_step:
            self._vis_editor.randomise(self._vis_rng)
        self._read(row)
        row["reward"][0] = reward
        # dm_control ends an episode with a discount: 0 is a terminal state, > 0 a cut-off.
        row["terminated"][0] = discount is not None and discount == 0
        row["truncated"][0] = (self.steps >= self.max_episode_steps
                               or (discount is not None and discount > 0))

    def _read(self, row: dict) -> None:
        if self.spec.is_robot:
            self.task.privileged_state(self.physics, row["state"])
            self.task.robot_observation(self.physics, row["observation"])
        else:
            task_registry.suite_state(self.task, self.physics, row["state"])
        for name in self.readings:
            row[name][0] = getattr(self.task, name)(self.physics)
        row["dynamics"][:] = self._params_array
        if self.pixels:
            row["pixels"][:] = self.render()
        row["terminated"][0] = False
        row["truncated"][0] = False

    def render_configuration(self, qpos, redraw: bool = True) -> np.ndarray:
        """Renders the world posed at joint positions ``qpos``, uint8 ``(size, size, 3)``.

        Sets the first ``len(qpos)`` entries of ``physics.data.qpos`` (velocities are left
        as they are, and no time passes), then, when ``redraw`` and a visual randomisation
        is set, draws fresh textures, colours, light and camera pose before rendering:
        images of chosen states, e.g. the training set of a perception model
        (``experiments/twist_readout_scale.py``). The episode's physics is changed: call
        :meth:`reset` before stepping again.

        Raises:
            ValueError: ``qpos`` is not a 1-D array of at most ``nq`` finite numbers.
        """
        qpos = np.asarray(qpos, dtype=np.float64)
        nq = self.physics.model.nq
        if qpos.ndim != 1 or not 1 <= len(qpos) <= nq:
            raise ValueError(f"qpos must be 1-D with 1 to {nq} entries, got shape {qpos.shape}")
        if not np.isfinite(qpos).all():
            raise ValueError(f"qpos must be finite, got {qpos}")
        self.physics.data.qpos[:len(qpos)] = qpos
        self.physics.forward()
        if redraw and self._vis_editor is not None:
            self._vis_editor.randomise(self._vis_rng)
        return self.render()

    def render(self, size: int | None = None, camera_id: int | None = None) -> np.ndarray:
        """Renders the current frame, uint8 ``(size, size, 3)``."""
        size = size or self.image_size
        camera = self.camera_id if camera_id is None else camera_id
        jitter = (self._vis_editor.jittered_view() if self._vis_editor is not None
                  and camera == self.camera_id else contextlib.nullcontext())
        try:
            with jitter:
                frame = self.physics.render(size, size, camera_id=camera)
        except Exception as err:  # GL errors come in many types; name the fix.
            raise rendering_error(err) from err
        return np.ascontiguousarray(frame)  # dm_control returns a vertically flipped view

