"""Apply dynamics parameters and visual randomisation to a live MuJoCo model.

Both editors keep a copy of the nominal model fields they touch and always edit from that
copy, so draws never compound across episodes.
"""

from __future__ import annotations

import contextlib

import mujoco
import numpy as np

from simdist.envs.randomisation import DynamicsParams, VisualRandomisation
from simdist.rendering import rendering_error
from simdist.envs.textures import ColourBank, TextureBank


def root_body_id(model: mujoco.MjModel) -> int:
    """The body that carries the model's free joint (or the first child of the world)."""
    free = np.flatnonzero(model.jnt_type == mujoco.mjtJoint.mjJNT_FREE)
    return int(model.jnt_bodyid[free[0]]) if len(free) else 1


class DynamicsEditor:
    """Writes a :class:`DynamicsParams` into a MuJoCo model, relative to its nominal values.

    Examples:
        >>> import mujoco
        >>> m = mujoco.MjModel.from_xml_string(
        ...     '<mujoco><worldbody><body><freejoint/><geom size=".1"/></body></worldbody></mujoco>')
        >>> editor = DynamicsEditor(m)
        >>> editor.apply(DynamicsParams(friction=0.5))
        >>> float(m.geom_friction[0, 0])
        0.5
    """

    def __init__(self, model: mujoco.MjModel):
        self.model = model
        # mj_setConst overwrites the qpos of the MjData it is given: use a scratch one.
        self._scratch = mujoco.MjData(model)
        self._root = root_body_id(model)
        self._nominal = {
            name: getattr(model, name).copy()
            for name in ("geom_friction", "body_mass", "body_inertia", "dof_damping",
                         "actuator_gainprm", "actuator_biasprm", "geom_solref", "geom_solimp")
        }

    def apply(self, params: DynamicsParams) -> None:
        """Sets the model to ``nominal x params`` (latency is handled by the simulation)."""
        m, n = self.model, self._nominal
        m.geom_friction[:] = n["geom_friction"]
        m.geom_friction[:, 0] *= params.friction
        m.body_mass[:] = n["body_mass"] * params.mass
        m.body_inertia[:] = n["body_inertia"] * params.mass
        if params.payload_kg > 0:
            root_mass = m.body_mass[self._root]
            # A payload spread over the root body: inertia grows with its mass.
            m.body_inertia[self._root] *= (root_mass + params.payload_kg) / root_mass
            m.body_mass[self._root] = root_mass + params.payload_kg
        m.dof_damping[:] = n["dof_damping"] * params.damping
        m.actuator_gainprm[:] = n["actuator_gainprm"]
        m.actuator_gainprm[:, 0] *= params.motor_strength
        m.actuator_biasprm[:] = n["actuator_biasprm"]
        # force = gain*ctrl + b0 + b1*q + b2*qdot: scaling gain and all biases scales force.
        m.actuator_biasprm[:, :3] *= params.motor_strength
        # Softer contact: longer time constant, proportionally larger compliance
        # (1 - impedance) and a wider transition zone. The time constant alone barely
        # moves MuJoCo's steady-state penetration at dm_control's impedances.
        m.geom_solref[:] = n["geom_solref"]
        m.geom_solref[:, 0] *= params.contact_softness
        m.geom_solimp[:] = n["geom_solimp"]
        compliance = (1.0 - n["geom_solimp"][:, :2]) * params.contact_softness
        m.geom_solimp[:, :2] = np.clip(1.0 - compliance, 1e-4, 0.9999)
        m.geom_solimp[:, 2] *= params.contact_softness
        # Subtree masses and invweights are derived from masses: recompute them.
        mujoco.mj_setConst(m, self._scratch)


class VisualEditor:
    """Randomises textures, colours, lights and camera pose of a dm_control physics.

    Only fields that never enter the dynamics are written (``tex_data``, ``mat_rgba``,
    ``geom_rgba``, ``light_*``, ``cam_*``), so visual randomisation cannot change physics.

    Args:
        physics: a ``dm_control.mujoco.Physics``.
        config: what to randomise.
        camera_id: the render camera whose pose may be jittered.

    Examples:
        >>> from simdist.envs import TargetDomain, get_task
        >>> physics, _, _ = get_task("cartpole-balance").build(TargetDomain(), seed=0)
        >>> mass, rgba = physics.model.body_mass.copy(), physics.model.mat_rgba.copy()
        >>> editor = VisualEditor(physics, VisualRandomisation(textures=None), camera_id=0)
        >>> editor.randomise(np.random.default_rng(0))  # no textures: nothing to upload to GL
        >>> bool((physics.model.mat_rgba != rgba).any())  # colours changed, dynamics did not
        True
        >>> bool((physics.model.body_mass == mass).all())
        True
    """

    def __init__(self, physics, config: VisualRandomisation, camera_id: int):
        self.physics, self.config, self.camera_id = physics, config, camera_id
        m = physics.model.ptr
        self._textures = (TextureBank(config.textures, config.bank_size, config.bank_seed)
                          if config.textures else None)
        self._colours = (ColourBank(config.colours, config.bank_size, config.bank_seed)
                         if config.colours else None)
        self.texture_ids = self._background_textures(m)
        untextured = (m.mat_texid < 0).all(axis=1)
        self._materials = np.flatnonzero(untextured)
        # Visible geoms without a material take their colour from geom_rgba.
        self._geoms = np.flatnonzero((m.geom_matid < 0) & (m.geom_rgba[:, 3] > 0))
        self._nominal = {name: getattr(m, name).copy() for name in
                         ("mat_rgba", "geom_rgba", "light_diffuse", "light_pos",
                          "light_pos0", "light_poscom0", "cam_pos", "cam_pos0",
                          "cam_poscom0")}
        self._ambient = m.vis.headlight.ambient.copy()
        # The camera-frame rotation of the current draw, applied to the rendered view
        # (``jittered_view``) rather than to the model: MuJoCo recomputes the orientation
        # of a camera that aims at a body (cartpole's "lookatcart") every step, so a
        # rotation written into cam_quat/cam_mat0 would be lost for it.
        self.view_rotation = np.eye(3)

    @staticmethod
    def _background_textures(m) -> list[int]:
        """Skybox textures plus the textures of materials on plane (floor) geoms."""
        ids = set(np.flatnonzero(m.tex_type == mujoco.mjtTexture.mjTEXTURE_SKYBOX).tolist())
        for matid in m.geom_matid[m.geom_type == mujoco.mjtGeom.mjGEOM_PLANE]:
            if matid >= 0:
                ids.update(int(t) for t in m.mat_texid[matid] if t >= 0)
        return sorted(ids)

    def randomise(self, rng: np.random.Generator) -> None:
        """Draws and writes one visual configuration; uploads changed textures."""
        m, c, n = self.physics.model.ptr, self.config, self._nominal
        if self._colours is not None:
            m.mat_rgba[self._materials, :3] = self._colours.sample(rng, len(self._materials))
            m.geom_rgba[self._geoms, :3] = self._colours.sample(rng, len(self._geoms))
        if c.lighting and m.nlight:
            scale = rng.uniform(*c.light_intensity, size=(m.nlight, 1))
            tint = rng.uniform(0.8, 1.0, size=(m.nlight, 3))
            m.light_diffuse[:] = np.clip(n["light_diffuse"] * scale * tint, 0, 1)
            offset = rng.uniform(-0.5, 0.5, size=n["light_pos"].shape)
            # Tracking lights/cameras are placed from the *0 / *com0 fields (set by
            # mj_setConst): write all so every mode sees this draw, none carries over.
            m.light_pos[:] = n["light_pos"] + offset
            m.light_pos0[:] = n["light_pos0"] + offset
            m.light_poscom0[:] = n["light_poscom0"] + offset
            m.vis.headlight.ambient[:] = self._ambient * rng.uniform(0.5, 1.5)
        if c.camera and m.ncam:
            i = self.camera_id
            offset = rng.uniform(-1, 1, 3) * c.camera_position_jitter
            m.cam_pos[i] = n["cam_pos"][i] + offset
            m.cam_pos0[i] = n["cam_pos0"][i] + offset
            m.cam_poscom0[i] = n["cam_poscom0"][i] + offset
            axis = rng.normal(size=3)
            angle = np.deg2rad(rng.uniform(-1, 1) * c.camera_angle_jitter_deg)
            jitter = np.zeros(4)
            mujoco.mju_axisAngle2Quat(jitter, axis / np.linalg.norm(axis), angle)
            jitter_mat = np.zeros(9)
            mujoco.mju_quat2Mat(jitter_mat, jitter)
            self.view_rotation = jitter_mat.reshape(3, 3)  # applied by jittered_view
        if (c.lighting and m.nlight) or (c.camera and m.ncam):
            # Cameras and lights are placed in mj_camlight during physics steps; without
            # this the frame would show the previous draw's lights and camera.
            mujoco.mj_camlight(m, self.physics.data.ptr)
        if self._textures is not None and self.texture_ids:
            for tex in self.texture_ids:
                h, w = int(m.tex_height[tex]), int(m.tex_width[tex])
                adr, nch = int(m.tex_adr[tex]), int(m.tex_nchannel[tex])
                img = self._textures.sample(rng, h, w)
                if nch == 4:
                    img = np.concatenate([img, np.full((h, w, 1), 255, np.uint8)], axis=-1)
                m.tex_data[adr:adr + h * w * nch] = img.reshape(-1)
            self._upload(self.texture_ids)

    @contextlib.contextmanager
    def jittered_view(self):
        """Inside, the camera's orientation (as MuJoCo placed it, whatever the camera's
        mode) carries this draw's rotation jitter. The physics' own orientation is restored
        on exit, so rendering twice does not rotate twice and the next step is unaffected."""
        if not self.config.camera or self.camera_id < 0:  # -1: MuJoCo's free camera
            yield
            return
        xmat = self.physics.data.ptr.cam_xmat
        own = xmat[self.camera_id].copy()
        xmat[self.camera_id] = (own.reshape(3, 3) @ self.view_rotation).ravel()
        try:
            yield
        finally:
            xmat[self.camera_id] = own

    def _upload(self, texture_ids) -> None:
        try:
            contexts = self.physics.contexts
            with contexts.gl.make_current() as ctx:
                for tex in texture_ids:
                    ctx.call(mujoco.mjr_uploadTexture, self.physics.model.ptr,
                             contexts.mujoco.ptr, tex)
        except Exception as err:  # GL failures surface as many types; name the fix.
            raise rendering_error(err) from err
