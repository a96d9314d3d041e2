"""Tabletop manipulation: block push, block lift and peg insertion with a Cartesian gripper.

The robot is a parallel-jaw gripper moved in Cartesian space, as the TWIST and SimDist
papers drive their arms: each action is a change of the end-effector's target position
of at most :data:`MAX_STEP` (2 cm) per axis per step, plus (push, lift) a jaw command in
[-1, 1] (-1 open, 1 closed). Three slide joints carry the gripper and stiff position
servos track the target, so the hand is a real dynamic body: it pushes and grasps through
MuJoCo contacts, it lags its target under load, and the randomised (or shifted) motor
strength, mass, friction, contact softness and latency all act on it. The arm's links
are not modelled: a 7-joint arm behind an operational-space controller would add
kinematics the tasks do not need and cost several times the simulation time per step on
2 CPU cores, while the contacts that decide success (jaws on the cube, peg on the hole's
walls) are the same.

- ``block-push``: push a 4 cm cube onto a goal marker; success: the cube's centre within
  5 cm of the goal at the end.
- ``block-lift``: grasp the cube and lift it; success: 10 cm above the table.
- ``peg-insertion``: the gripper holds a square peg over a square hole with 1.5 mm
  clearance per side; success: the peg's tip 2.5 cm into the hole.

Initial conditions come from a grid (``init="narrow"``: 3 x 3 points 2 cm apart, or
``"wide"``: 5 x 5 points 4 cm apart), one point drawn per episode for the cube (and
another for the goal) or the hole. Control runs at 20 Hz; episodes last 150 steps.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np
from dm_control.suite import base, common

from simdist.envs.layout import Layout
from simdist.envs.quadruped import small_texture_assets

CONTROL_TIMESTEP = 0.05  # 20 Hz
MAX_STEP = 0.02  # metres per axis per step
CUBE_HALF = 0.02
PEG_HALF, PEG_LENGTH = 0.01, 0.06
CLEARANCE = 0.0015
HOLE_TOP, INSERT_DEPTH = 0.04, 0.025
PUSH_SUCCESS_M, LIFT_SUCCESS_M = 0.05, 0.10
#: Grid of initial positions: (points per axis, spacing in metres).
GRIDS = {"narrow": (3, 0.02), "wide": (5, 0.04)}
WORKSPACE = np.array([[-0.25, -0.25, 0.0], [0.25, 0.25, 0.25]])  # the target's box

_GRIPPER = """
    <body name="gripper" pos="0 0 0.12" gravcomp="1">
      <joint name="grip_x" type="slide" axis="1 0 0" range="-0.3 0.3" damping="25"/>
      <joint name="grip_y" type="slide" axis="0 1 0" range="-0.3 0.3" damping="25"/>
      <joint name="grip_z" type="slide" axis="0 0 1" range="-0.15 0.2" damping="25"/>
      <geom name="palm" type="box" size="0.015 0.045 0.01" mass="0.5" rgba=".6 .6 .65 1"/>
      <site name="wrist" pos="0 0 0" size="0.005"/>
      {hand}
    </body>"""
_JAWS = """
      <body name="jaw_left" pos="0 0.035 -0.035" gravcomp="1">
        <joint name="jaw_left" type="slide" axis="0 -1 0" range="0 0.03" damping="3"/>
        <geom name="jaw_left" type="box" size="0.012 0.005 0.025" mass="0.05"
              friction="1.5 0.02 0.001" rgba=".3 .3 .35 1"/>
      </body>
      <body name="jaw_right" pos="0 -0.035 -0.035" gravcomp="1">
        <joint name="jaw_right" type="slide" axis="0 1 0" range="0 0.03" damping="3"/>
        <geom name="jaw_right" type="box" size="0.012 0.005 0.025" mass="0.05"
              friction="1.5 0.02 0.001" rgba=".3 .3 .35 1"/>
      </body>"""
_PEG = """
      <geom name="peg" type="box" pos="0 0 -{peg_centre}" size="{half} {half} {half_len}"
            mass="0.05" rgba=".85 .65 .2 1"/>"""
_CUBE = """
    <body name="object" pos="0 0 {half}">
      <freejoint name="object"/>
      <geom name="object" type="box" size="{half} {half} {half}" mass="0.1"
            friction="1 0.01 0.001" rgba=".8 .25 .2 1"/>
    </body>
    <site name="goal" type="cylinder" pos="0.15 0 0.001" size="0.03 0.001"
          rgba=".2 .8 .3 .6"/>"""
_HOLE = """
    <body name="hole" pos="0.05 0 0">
      {walls}
      <site name="hole" pos="0 0 {top}" size="0.003"/>
    </body>"""
_JAW_ACTUATORS = """
    <position name="jaws" tendon="jaws" kp="200" ctrlrange="0 0.03" forcerange="-10 10"/>"""


def _walls(inner: float, outer: float = 0.05) -> str:
    """Four boxes around a square hole of half-width ``inner``."""
    mid, half_w = (inner + outer) / 2, (outer - inner) / 2
    top = HOLE_TOP / 2
    boxes = [(mid, 0, half_w, outer), (-mid, 0, half_w, outer),
             (0, mid, inner, half_w), (0, -mid, inner, half_w)]
    return "\n      ".join(
        f'<geom name="wall_{i}" type="box" pos="{x} {y} {top}" size="{sx} {sy} {top}" '
        f'rgba=".35 .45 .6 1"/>' for i, (x, y, sx, sy) in enumerate(boxes))


def make_model(kind: str, texture_size: int = 64) -> tuple[str, dict]:
    """``(xml, assets)`` of the tabletop scene for ``kind`` ("cube" or "peg")."""
    if kind == "cube":
        hand, scene = _JAWS, _CUBE.format(half=CUBE_HALF)
        tendon = ('<tendon><fixed name="jaws"><joint joint="jaw_left" coef="0.5"/>'
                  '<joint joint="jaw_right" coef="0.5"/></fixed></tendon>'
                  '<equality><joint joint1="jaw_left" joint2="jaw_right"/></equality>')
        jaws = _JAW_ACTUATORS
    elif kind == "peg":
        hand = _PEG.format(half=PEG_HALF, half_len=PEG_LENGTH / 2,
                           peg_centre=0.01 + PEG_LENGTH / 2)
        scene = _HOLE.format(walls=_walls(PEG_HALF + CLEARANCE), top=HOLE_TOP)
        tendon, jaws = "", ""
    else:
        raise ValueError(f"unknown scene kind {kind!r}; valid: cube, peg")
    xml = f"""<mujoco model="tabletop_{kind}">
  <include file="./common/skybox.xml"/>
  <include file="./common/visual.xml"/>
  <include file="./common/materials.xml"/>
  <option timestep="0.002" cone="elliptic" impratio="10"/>
  <worldbody>
    <light name="light" pos="0 0 1.5" dir="0 0 -1" diffuse=".7 .7 .7"/>
    <camera name="front" pos="0.33 0 0.3" xyaxes="0 1 0 -0.67 0 0.74" fovy="50"/>
    <camera name="top" pos="0 0 0.8" xyaxes="1 0 0 0 1 0"/>
    <geom name="table" type="plane" size="0.4 0.4 0.05" material="grid"
          friction="1 0.01 0.001"/>
    {_GRIPPER.format(hand=hand)}
    {scene}
  </worldbody>
  {tendon}
  <actuator>
    <position name="grip_x" joint="grip_x" kp="400" ctrlrange="-0.3 0.3"/>
    <position name="grip_y" joint="grip_y" kp="400" ctrlrange="-0.3 0.3"/>
    <position name="grip_z" joint="grip_z" kp="400" ctrlrange="-0.15 0.2"/>{jaws}
  </actuator>
  <sensor><force name="wrist_force" site="wrist"/></sensor>
</mujoco>"""
    return xml, small_texture_assets(common.ASSETS, texture_size)


def grid_points(init: str) -> np.ndarray:
    """The ``(n * n, 2)`` offsets of an initial-condition grid, centred on 0.

    Examples:
        >>> grid_points("narrow").shape, float(grid_points("wide").max())
        ((9, 2), 0.08)
    """
    if init not in GRIDS:
        raise ValueError(f"unknown initial-condition grid {init!r}; valid: {sorted(GRIDS)}")
    n, spacing = GRIDS[init]
    axis = (np.arange(n) - (n - 1) / 2) * spacing
    return np.stack(np.meshgrid(axis, axis, indexing="ij"), -1).reshape(-1, 2)


class TabletopTask(base.Task):
    """The gripper, its Cartesian delta actions and the readings every tabletop task shares.

    Subclasses set the scene (:meth:`place`), the reward and :meth:`success`.

    Examples:
        >>> from simdist.envs import make_env
        >>> env = make_env("block-lift", seed=0, task_kwargs={"init": "wide"})
        >>> type(env.sims[0].task).__name__, env.action_spec.shape
        ('BlockLift', torch.Size([4]))
    """

    kind = "cube"
    jaws = True

    def __init__(self, init: str = "narrow", random=None):
        self.grid = grid_points(init)
        self.init = init
        self._target = np.zeros(3)
        super().__init__(random=random)

    # -- actions: a change of the hand's target position (and the jaws) ----------------
    def action_bounds(self, physics) -> tuple[np.ndarray, np.ndarray]:
        n = 4 if self.jaws else 3
        return -np.ones(n, np.float32), np.ones(n, np.float32)

    def before_step(self, action, physics):
        action = np.clip(np.asarray(action, np.float64), -1.0, 1.0)
        self._target = np.clip(self._target + MAX_STEP * action[:3], *WORKSPACE)
        ctrl = physics.data.ptr.ctrl
        ctrl[:3] = self._target - self._home
        if self.jaws:  # -1 open (0.0 of travel) .. 1 closed (0.03)
            ctrl[3] = 0.015 * (action[3] + 1.0)

    def initialize_episode(self, physics):
        m = physics.model.ptr
        self._home = m.body_pos[m.body("gripper").id].copy()
        self._grip = m.body("gripper").id
        start = np.array([-0.1, 0.0, 0.15 if self.kind == "peg" else 0.12])
        physics.data.ptr.qpos[:3] = start - self._home
        physics.data.ptr.ctrl[:3] = start - self._home
        self._target = start.copy()
        self.place(physics)
        super().initialize_episode(physics)

    def place(self, physics) -> None:
        raise NotImplementedError

    def grid_point(self) -> np.ndarray:
        return self.grid[self.random.randint(len(self.grid))]

    # -- readings ------------------------------------------------------------------
    def hand(self, physics) -> np.ndarray:
        return physics.data.ptr.xpos[self._grip].copy()

    def hand_velocity(self, physics) -> np.ndarray:
        return physics.data.ptr.qvel[:3].copy()

    def get_observation(self, physics):
        layout = self.state_layout(physics)
        flat = np.empty(layout.size)
        self.privileged_state(physics, flat)
        return layout.split(flat)

    def get_termination(self, physics):
        return None


class _CubeTask(TabletopTask):
    #: where the cube's grid is centred on the table
    centre = np.array([0.0, 0.0])

    def place(self, physics):
        m, d = physics.model.ptr, physics.data.ptr
        cube = self.grid_point() + self.centre
        d.qpos[3:5] = 0.0  # the jaws start open
        j = m.joint("object").qposadr[0]
        d.qpos[j:j + 3] = [cube[0], cube[1], CUBE_HALF]
        d.qpos[j + 3:j + 7] = [1, 0, 0, 0]
        self._object = m.body("object").id
        self._goal_site = m.site("goal").id
        self.place_goal(physics, cube)

    def place_goal(self, physics, cube) -> None:
        pass

    def cube(self, physics) -> np.ndarray:
        return physics.data.ptr.xpos[self._object].copy()

    def goal(self, physics) -> np.ndarray:
        return physics.model.ptr.site_pos[self._goal_site].copy()

    def jaw_opening(self, physics) -> float:
        return float(physics.data.ptr.qpos[3])

    def observation_layout(self, physics) -> Layout:
        return Layout.from_sizes(OrderedDict(hand_pos=3, hand_vel=3, jaws=1, goal=3))

    def state_layout(self, physics) -> Layout:
        return Layout.from_sizes(OrderedDict(hand_pos=3, hand_vel=3, jaws=1, object_pos=3,
                                             object_quat=4, object_vel=6, goal=3))

    def robot_observation(self, physics, out) -> None:
        np.concatenate([self.hand(physics), self.hand_velocity(physics),
                        (self.jaw_opening(physics),), self.goal(physics)], out=out)

    def privileged_state(self, physics, out) -> None:
        d = physics.data.ptr
        j = physics.model.ptr.joint("object")
        q, v = j.qposadr[0], j.dofadr[0]
        np.concatenate([self.hand(physics), self.hand_velocity(physics),
                        (self.jaw_opening(physics),), d.qpos[q:q + 3], d.qpos[q + 3:q + 7],
                        d.qvel[v:v + 6], self.goal(physics)], out=out)


class BlockPush(_CubeTask):
    """Push the cube onto the goal marker: 15 cm ahead of it, moved by half a grid point
    drawn on its own (so at least 9 cm away on the wide grid).

    Examples:
        >>> from simdist.envs import make_env
        >>> env = make_env("block-push", seed=0)
        >>> env.state_layout.names()[:4], float(env.reset()["success"])
        (['hand_pos', 'hand_vel', 'jaws', 'object_pos'], 0.0)
    """

    centre = np.array([-0.05, 0.0])

    def place_goal(self, physics, cube):
        goal = cube + np.array([0.15, 0.0]) + 0.5 * self.grid_point()
        physics.model.ptr.site_pos[self._goal_site] = [goal[0], goal[1], 0.001]

    def get_reward(self, physics):
        cube, hand = self.cube(physics), self.hand(physics)
        to_goal = np.linalg.norm(cube[:2] - self.goal(physics)[:2])
        reach = np.linalg.norm(hand - cube)
        return float(0.3 * (1 - np.tanh(10 * reach)) + (1 - np.tanh(10 * to_goal)))

    def success(self, physics) -> float:
        return float(np.linalg.norm(self.cube(physics)[:2] - self.goal(physics)[:2])
                     < PUSH_SUCCESS_M)


class BlockLift(_CubeTask):
    """Grasp the cube and lift it 10 cm (the goal marks the height above the cube).

    Examples:
        >>> from simdist.envs import make_env
        >>> env = make_env("block-lift", seed=0)
        >>> env.observation_layout.names()
        ['hand_pos', 'hand_vel', 'jaws', 'goal']
    """

    def place_goal(self, physics, cube):
        physics.model.ptr.site_pos[self._goal_site] = [cube[0], cube[1],
                                                       CUBE_HALF + LIFT_SUCCESS_M]
        physics.model.ptr.site_rgba[self._goal_site, 3] = 0.0  # a height: not drawn

    def get_reward(self, physics):
        cube, hand = self.cube(physics), self.hand(physics)
        reach = np.linalg.norm(hand - cube - np.array([0, 0, 0.025]))
        height = min(max(cube[2] - CUBE_HALF, 0.0) / LIFT_SUCCESS_M, 1.0)
        return float(0.3 * (1 - np.tanh(10 * reach)) + height)

    def success(self, physics) -> float:
        return float(self.cube(physics)[2] - CUBE_HALF >= LIFT_SUCCESS_M)


class PegInsertion(TabletopTask):
    """Insert the held peg into the hole. The robot is told where the hole is
    (``hole_nominal``); ``hole_offset_m`` moves the real hole from there (a calibration
    error the robot cannot see but can feel).

    Examples:
        >>> from simdist.envs import make_env
        >>> env = make_env("peg-insertion", seed=0, task_kwargs={"hole_offset_m": (0.003, 0)})
        >>> env.action_spec.shape, env.observation_layout.names()
        (torch.Size([3]), ['hand_pos', 'hand_vel', 'hole_nominal', 'wrist_force'])
    """

    kind, jaws = "peg", False

    def __init__(self, init: str = "narrow", hole_offset_m=(0.0, 0.0), random=None):
        self.hole_offset = np.asarray(hole_offset_m, np.float64)
        super().__init__(init=init, random=random)

    def place(self, physics):
        m = physics.model.ptr
        self._hole = m.body("hole").id
        self._hole_site = m.site("hole").id
        self._peg = m.geom("peg").id
        nominal = self.grid_point() + np.array([0.05, 0.0])
        self.nominal = np.array([nominal[0], nominal[1], HOLE_TOP])
        m.body_pos[self._hole, :2] = nominal + self.hole_offset

    def hole(self, physics) -> np.ndarray:
        return physics.data.ptr.site_xpos[self._hole_site].copy()

    def peg_tip(self, physics) -> np.ndarray:
        d = physics.data.ptr
        return d.geom_xpos[self._peg] - np.array([0, 0, PEG_LENGTH / 2])

    def insertion(self, physics) -> float:
        """How deep the tip is below the hole's rim, as a fraction of the success depth."""
        tip, hole = self.peg_tip(physics), self.hole(physics)
        inside = np.abs(tip[:2] - hole[:2]).max() < PEG_HALF + CLEARANCE
        return float(np.clip((hole[2] - tip[2]) / INSERT_DEPTH, 0, 1)) if inside else 0.0

    def get_reward(self, physics):
        tip, hole = self.peg_tip(physics), self.hole(physics)
        align = np.linalg.norm(tip[:2] - hole[:2])
        return float(0.5 * (1 - np.tanh(20 * align)) + self.insertion(physics))

    def success(self, physics) -> float:
        return float(self.insertion(physics) >= 1.0)

    def observation_layout(self, physics) -> Layout:
        return Layout.from_sizes(OrderedDict(hand_pos=3, hand_vel=3, hole_nominal=3,
                                             wrist_force=3))

    def state_layout(self, physics) -> Layout:
        return Layout.from_sizes(OrderedDict(hand_pos=3, hand_vel=3, peg_tip=3, hole=3))

    def robot_observation(self, physics, out) -> None:
        force = physics.data.ptr.sensordata[:3]
        np.concatenate([self.hand(physics), self.hand_velocity(physics), self.nominal,
                        np.arcsinh(force)], out=out)

    def privileged_state(self, physics, out) -> None:
        np.concatenate([self.hand(physics), self.hand_velocity(physics),
                        self.peg_tip(physics), self.hole(physics)], out=out)


TASK_CLASSES: dict[str, type[TabletopTask]] = {
    "block-push": BlockPush, "block-lift": BlockLift, "peg-insertion": PegInsertion}


__all__ = ["BlockLift", "BlockPush", "PegInsertion", "TabletopTask", "TASK_CLASSES",
           "make_model", "grid_points", "MAX_STEP", "CONTROL_TIMESTEP"]
