"""Turn (predicted) privileged states into 3-D body positions with MuJoCo kinematics."""

from __future__ import annotations

import mujoco
import numpy as np


class BodyPositions:
    """Forward kinematics on a scratch ``MjData``: ``qpos -> xpos`` of chosen bodies.

    A probe decodes latents into the privileged state, whose ``qpos`` part places every
    body; this class turns those into points a 3-D viewer can draw.

    Args:
        model: the env's ``mujoco.MjModel`` (``env.sims[0].physics.model.ptr``).
        bodies: body names to report.

    Examples:
        >>> m = mujoco.MjModel.from_xml_string(
        ...     '<mujoco><worldbody><body name="b"><freejoint/><geom size=".1"/></body></worldbody></mujoco>')
        >>> BodyPositions(m, ["b"])(np.array([[1.0, 2, 3, 1, 0, 0, 0]]))[0, 0].tolist()
        [1.0, 2.0, 3.0]
    """

    def __init__(self, model: mujoco.MjModel, bodies):
        self.model, self.data = model, mujoco.MjData(model)
        self.names = list(bodies)
        self.ids = []
        for name in self.names:
            i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
            if i < 0:
                raise ValueError(f"no body {name!r} in the model")
            self.ids.append(i)

    def __call__(self, qpos: np.ndarray) -> np.ndarray:
        """``qpos [..., nq]`` -> positions ``[..., len(bodies), 3]``."""
        qpos = np.asarray(qpos, dtype=np.float64)
        if qpos.shape[-1] != self.model.nq:
            raise ValueError(f"qpos must end with {self.model.nq}, got {qpos.shape}")
        flat = qpos.reshape(-1, self.model.nq)
        out = np.empty((len(flat), len(self.ids), 3))
        for k, q in enumerate(flat):
            self.data.qpos[:] = q
            mujoco.mj_kinematics(self.model, self.data)
            out[k] = self.data.xpos[self.ids]
        return out.reshape(*qpos.shape[:-1], len(self.ids), 3)


def decode_plans(world_model, probe, latent, actions, qpos: slice, bodies: BodyPositions):
    """Plans in 3-D: roll ``actions [..., H, A]`` from ``latent [L]`` through the world
    model, decode each predicted latent with the ``probe`` (latent -> privileged state),
    take its ``qpos`` part and place the key bodies with forward kinematics.

    Returns ``[..., H, n_bodies, 3]``.
    """
    import torch

    from simdist.utils.device import module_device

    device = module_device(world_model)  # the policy hands latents and plans back on CPU
    latent, actions = latent.to(device), actions.to(device)
    with torch.no_grad():
        lead = actions.shape[:-2]
        z0 = latent.expand(*lead, latent.shape[-1])
        states = probe(world_model.rollout(z0, actions))
    return bodies(states[..., qpos].cpu().numpy())
