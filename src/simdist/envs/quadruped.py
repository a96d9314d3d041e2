"""Quadruped locomotion at a commanded forward speed, on flat ground or a slope.

Built on dm_control's quadruped model. Differences from ``suite.quadruped.walk``: the
robot starts upright facing +x (dm_control draws a uniformly random orientation), the
command is drawn per episode from a small set of speeds (like the SimDist reference's
three speeds), the floor can be inclined, rangefinders give an onboard height scan, and
the task reports forward progress along the direction of travel in metres.
"""

from __future__ import annotations

from collections import OrderedDict

import mujoco
import numpy as np
from dm_control.rl import control
from dm_control.suite import base, common
from dm_control.suite import quadruped as dmc_quadruped
from lxml import etree

from simdist.envs.layout import Layout

CONTROL_TIMESTEP = 0.02  # 50 Hz, the reference control rate
_TOE_FORCE_SENSORS = ("force_toe_front_left", "force_toe_front_right",
                      "force_toe_back_right", "force_toe_back_left")
# Gaussian tolerance: reward 0.1 at one margin (= commanded speed) outside the band.
_GAUSS_SCALE = np.sqrt(-2.0 * np.log(0.1))


def make_model(slope_deg: float, floor_size: float = 60.0, texture_size: int = 64) -> tuple:
    """Returns ``(xml, assets)`` for the quadruped on a (possibly inclined) floor.

    Textures are shrunk to ``texture_size`` so per-step texture randomisation uploads
    kilobytes, not the 11 MB of dm_control's 800 px skybox.
    """
    xml = dmc_quadruped.make_model(floor_size=floor_size, rangefinders=True)
    mjcf = etree.XML(xml, etree.XMLParser(remove_blank_text=True))
    floor = mjcf.find(".//geom[@name='floor']")
    # Rotating about -y tilts +x uphill: the robot climbs when it walks forward.
    half = -np.deg2rad(slope_deg) / 2
    floor.attrib["quat"] = f"{np.cos(half)} 0 {np.sin(half)} 0"
    return etree.tostring(mjcf), small_texture_assets(common.ASSETS, texture_size)


def small_texture_assets(assets: dict, size: int) -> dict:
    """dm_control's common assets with skybox and floor textures resized to ``size``."""
    out = dict(assets)
    for key, old in (("./common/skybox.xml", 'width="800" height="800"'),
                     ("./common/materials.xml", 'width="300" height="300"')):
        text = out[key].decode() if isinstance(out[key], bytes) else out[key]
        if old not in text:
            raise RuntimeError(f"unexpected dm_control asset {key}: texture size changed")
        out[key] = text.replace(old, f'width="{size}" height="{size}"').encode()
    return out


def place_without_contact(physics, orientation, joint_qpos_index, joint_angles,
                          step: float = 0.01, max_attempts: int = 10_000) -> None:
    """Sets the free root's orientation and the joint angles, then raises the robot in
    ``step`` increments until nothing touches.

    dm_control's ``quadruped._find_non_contacting_height`` does the same for the root
    alone: it calls ``physics.reset_context()`` on every try, which resets ``qpos`` to the
    model's default pose, so joint angles written before it are lost. Here they are
    written inside each try.

    Raises:
        RuntimeError: if no contact-free height is found in ``max_attempts`` steps.
    """
    for attempt in range(max_attempts):
        try:
            with physics.reset_context():
                root = physics.named.data.qpos["root"]
                root[:3] = 0.0, 0.0, attempt * step
                root[3:] = orientation
                physics.data.qpos[joint_qpos_index] = joint_angles
        except control.PhysicsError:  # a full contact buffer: go higher
            continue
        if physics.data.ncon == 0:
            return
    raise RuntimeError(f"no contact-free start height within {max_attempts * step:.0f} m")


class QuadrupedLocomotion(base.Task):
    """Walk forward (uphill on a slope) at a commanded speed, staying upright.

    Reward: ``upright ** upright_power * speed_tracking`` with ``upright = (1 + n_body .
    n_ground) / 2`` and a Gaussian tolerance of the forward velocity around the command
    (1 inside +-10% of the command, 0.1 one command-width outside).

    Args:
        speeds: commanded forward speeds (m/s), one drawn per episode.
        slope_deg: floor incline; forward is up the slope.
        slope_range_deg: ``(low, high)``: draw the incline per episode instead,
            uniformly in the range (negative is downhill); ``None`` keeps ``slope_deg``.
            The floor is a plane, so its tilt is edited in the compiled model in place.
        upside_down_termination: end the episode in a terminal state once the body's
            vertical axis makes a cosine below this with the world's (the body-frame
            gravity reading's z; -0.5: tilted 120 degrees, on its back), as a person
            sets a fallen robot back on its feet when recording real data. ``None``
            (the default): episodes run to their step limit, as dm_control's.
        upright_power: the exponent of the upright term (1, the default: the reward every
            expert and record before 2026-12-05 used). The plain term still pays 0.93 at
            30 degrees of tilt, where this quadruped rears up before it goes over the
            tail; a power of 10 pays half there (0.93 at 10 degrees), so a planner that
            reads the reward sees the rearing before the fall.
        random: seed or ``numpy.random.RandomState``.

    Examples:
        >>> physics = dmc_quadruped.Physics.from_xml_string(*make_model(slope_deg=8.0))
        >>> task = QuadrupedLocomotion(speeds=(0.5,), slope_deg=8.0, random=0)
        >>> with physics.reset_context():
        ...     task.initialize_episode(physics)
        >>> task.command, task.observation_layout(physics).size, task.forward_progress(physics)
        (0.5, 89, 0.0)
    """

    def __init__(self, speeds=(0.25, 0.5, 0.75), slope_deg: float = 0.0,
                 slope_range_deg: tuple | None = None,
                 upside_down_termination: float | None = None, upright_power: float = 1.0,
                 random=None):
        speeds = tuple(float(s) for s in speeds)
        if not speeds or not all(np.isfinite(s) and s > 0 for s in speeds):
            raise ValueError(f"speeds must be a non-empty list of positive, finite m/s, "
                             f"got {speeds}")
        self.speeds = speeds
        if slope_range_deg is not None:
            low, high = (float(v) for v in slope_range_deg)
            if not (np.isfinite(low) and np.isfinite(high) and -30 <= low <= high <= 30):
                raise ValueError(f"slope_range_deg must be (low, high) within [-30, 30], "
                                 f"got {slope_range_deg}")
            slope_range_deg = (low, high)
        self.slope_range_deg = slope_range_deg
        if upside_down_termination is not None and not -1 < upside_down_termination < 1:
            raise ValueError(f"upside_down_termination must be a cosine in (-1, 1) or None, "
                             f"got {upside_down_termination}")
        self.upside_down_termination = upside_down_termination
        if not (np.isfinite(upright_power) and upright_power > 0):
            raise ValueError(f"upright_power must be a positive, finite exponent, got "
                             f"{upright_power}")
        self.upright_power = float(upright_power)
        self._set_slope(float(slope_deg))
        self.command = self.speeds[0]
        self._start = np.zeros(3)
        self._idx = None
        super().__init__(random=random)

    def _set_slope(self, slope_deg: float) -> None:
        self.slope_deg = slope_deg
        theta = np.deg2rad(slope_deg)
        self.forward = np.array([np.cos(theta), 0.0, np.sin(theta)])
        self.ground_normal = np.array([-np.sin(theta), 0.0, np.cos(theta)])

    # -- indices into MjData, computed once per model -------------------------------
    def _indices(self, physics):
        m = physics.model.ptr
        hinges = np.flatnonzero(m.jnt_type == mujoco.mjtJoint.mjJNT_HINGE)

        def sensor(name):
            i = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, name)
            return np.arange(m.sensor_adr[i], m.sensor_adr[i] + m.sensor_dim[i])

        rf = np.flatnonzero(m.sensor_type == mujoco.mjtSensor.mjSENS_RANGEFINDER)
        return dict(
            torso=mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "torso"),
            floor=mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor"),
            qpos=m.jnt_qposadr[hinges], qvel=m.jnt_dofadr[hinges],
            gyro=sensor("imu_gyro"), accel=sensor("imu_accel"), vel=sensor("velocimeter"),
            toe_force=np.concatenate([sensor(s) for s in _TOE_FORCE_SENSORS]),
            rangefinder=m.sensor_adr[rf],
        )

    def initialize_episode(self, physics):
        if self._idx is None:
            self._idx = self._indices(physics)
        self.command = self.speeds[self.random.randint(len(self.speeds))]
        if self.slope_range_deg is not None:
            self._set_slope(self.random.uniform(*self.slope_range_deg))
            half = -np.deg2rad(self.slope_deg) / 2  # as make_model tilts the floor
            physics.model.ptr.geom_quat[self._idx["floor"]] = [np.cos(half), 0, np.sin(half), 0]
        yaw = self.random.uniform(-0.1, 0.1)
        # Stand on the incline: pitch the body with the slope, then a small yaw.
        pitch = np.zeros(4)
        mujoco.mju_axisAngle2Quat(pitch, np.array([0.0, 1.0, 0.0]), -np.deg2rad(self.slope_deg))
        turn = np.zeros(4)
        mujoco.mju_axisAngle2Quat(turn, self.ground_normal, yaw)
        orientation = np.zeros(4)
        mujoco.mju_mulQuat(orientation, turn, pitch)
        joints = self.random.uniform(-0.05, 0.05, len(self._idx["qpos"]))
        place_without_contact(physics, orientation, self._idx["qpos"], joints)
        self._start = physics.data.xpos[self._idx["torso"]].copy()
        super().initialize_episode(physics)

    # -- readings --------------------------------------------------------------------
    # Readings use the raw ``mujoco.MjData`` (``physics.data.ptr``): dm_control's wrapper
    # costs microseconds per attribute access, which adds up at thousands of steps/s.
    def forward_velocity(self, physics) -> float:
        d = physics.data.ptr
        rot = d.xmat[self._idx["torso"]].reshape(3, 3)
        return float(rot @ d.sensordata[self._idx["vel"]] @ self.forward)

    def forward_progress(self, physics) -> float:
        """Metres travelled along the direction of travel since the episode began.

        Read from the torso's horizontal displacement along +x, divided by the slope's
        cosine (the distance along the incline a walk in its plane covers): a vertical
        movement of the torso (settling onto the legs after the drop from the start
        height, bobbing in the gait) is not progress. Projecting the 3-D displacement on
        the incline instead counted the ~7.6 cm settle at the start as -1.6 cm of
        progress on a 12 degree slope. On flat ground both readings are the same.
        """
        dx = physics.data.ptr.xpos[self._idx["torso"], 0] - self._start[0]
        return float(dx / self.forward[0])

    def get_reward(self, physics):
        rot = physics.data.ptr.xmat[self._idx["torso"]].reshape(3, 3)
        # the floor keeps a rounding error below -1 from a NaN under a fractional power
        upright = max((1.0 + rot[:, 2] @ self.ground_normal) / 2.0, 0.0) ** self.upright_power
        v = self.forward_velocity(physics)
        low, high = 0.9 * self.command, 1.1 * self.command
        gap = max(low - v, v - high, 0.0) / self.command
        return upright * float(np.exp(-0.5 * (gap * _GAUSS_SCALE) ** 2))

    def get_termination(self, physics):
        """0 (a terminal state, dm_control's convention) once the robot is upside down by
        ``upside_down_termination``; ``None`` (go on) otherwise."""
        if self.upside_down_termination is None:
            return None
        # xmat's last row is the world's vertical in the body frame (the gravity reading)
        up = physics.data.ptr.xmat[self._idx["torso"], 8]
        return 0.0 if up < self.upside_down_termination else None

    def observation_layout(self, physics) -> Layout:
        n_hinge = len(self._idx["qpos"])
        return Layout.from_sizes(OrderedDict(
            joint_pos=n_hinge, joint_vel=n_hinge, actuator_state=physics.model.na,
            gyro=3, accelerometer=3, gravity=3, velocimeter=3, toe_force=12, command=1,
            height_scan=len(self._idx["rangefinder"])))

    def state_layout(self, physics) -> Layout:
        m = physics.model
        return Layout.from_sizes(OrderedDict(qpos=m.nq, qvel=m.nv, act=m.na, command=1))

    def robot_observation(self, physics, out: np.ndarray) -> None:
        """Writes what the robot can measure (proprioception + height scan) into ``out``."""
        d, i = physics.data.ptr, self._idx
        rot = d.xmat[i["torso"]].reshape(3, 3)
        rf = d.sensordata[i["rangefinder"]]
        np.concatenate([
            d.qpos[i["qpos"]], d.qvel[i["qvel"]], d.act,
            d.sensordata[i["gyro"]], d.sensordata[i["accel"]], rot[2],  # gravity in body frame
            d.sensordata[i["vel"]], np.arcsinh(d.sensordata[i["toe_force"]]), (self.command,),
            np.where(rf == -1.0, 1.0, np.tanh(rf)),  # -1 means no hit: saturate like dm_control
        ], out=out)

    def privileged_state(self, physics, out: np.ndarray) -> None:
        d = physics.data.ptr
        np.concatenate([d.qpos, d.qvel, d.act, (self.command,)], out=out)

    def get_observation(self, physics):
        """dm_control-style observation dict (the fast path is :meth:`robot_observation`)."""
        layout = self.observation_layout(physics)
        flat = np.empty(layout.size)
        self.robot_observation(physics, flat)
        return layout.split(flat)
