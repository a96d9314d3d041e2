"""rerun-sdk recordings of planning episodes: robot, plans in 3-D, executed path, traces.

Headless by default: a recording goes to an ``.rrd`` file that the rerun viewer opens
(``rerun file.rrd``). ``spawn=True`` also starts a local viewer process.
"""

from __future__ import annotations

import mujoco
import numpy as np
import rerun as rr


class PlanningRecorder:
    """Logs one control step at a time to a rerun recording.

    Entity paths: ``world/robot/geoms`` (MuJoCo geoms as points sized by the geom),
    ``world/robot/<body>`` (key bodies), ``world/plan/<body>`` (the chosen plan, one line
    strip per key body), ``world/elites/<body>`` (top-k sampled plans, faded),
    ``world/executed/<body>`` (the path actually taken), and ``plots/reward/predicted``,
    ``plots/reward/actual``, ``plots/value/predicted`` time series.

    Args:
        path: ``.rrd`` file to write (``None``: no file, e.g. with ``spawn``).
        application_id: rerun application id.
        spawn: also start a local rerun viewer.

    Examples:
        >>> import tempfile, os
        >>> path = os.path.join(tempfile.mkdtemp(), "demo.rrd")
        >>> rec = PlanningRecorder(path)
        >>> rec.log_scalars(0, predicted_reward=1.0, actual_reward=0.9)
        >>> rec.close(); os.path.getsize(path) > 0
        True
    """

    def __init__(self, path: str | None, application_id: str = "simdist", spawn: bool = False):
        self.stream = rr.RecordingStream(application_id)
        if path is not None:
            self.stream.save(path)
        if spawn:
            self.stream.spawn()
        self.path = path
        self._executed: dict[str, list] = {}

    def _time(self, step: int) -> None:
        self.stream.set_time("step", sequence=int(step))

    def log_robot(self, step: int, model: mujoco.MjModel, data: mujoco.MjData,
                  bodies=()) -> None:
        """Draws every geom (as a point with its size) and records the key bodies' path."""
        self._time(step)
        visible = model.geom_rgba[:, 3] > 0
        self.stream.log("world/robot/geoms", rr.Points3D(
            data.geom_xpos[visible], radii=model.geom_size[visible, 0].clip(0.005, 0.2),
            colors=(model.geom_rgba[visible, :3] * 255).astype(np.uint8)))
        for name in bodies:
            position = data.xpos[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)]
            self._executed.setdefault(name, []).append(position.copy())
            self.stream.log(f"world/robot/{name}", rr.Points3D([position], radii=0.03))
            self.stream.log(f"world/executed/{name}",
                            rr.LineStrips3D([np.array(self._executed[name])],
                                            colors=[[40, 200, 80]]))

    def log_plan(self, step: int, plan: np.ndarray, elites: np.ndarray | None = None,
                 names=()) -> None:
        """``plan [H, n_bodies, 3]``; ``elites [K, H, n_bodies, 3]`` (best first)."""
        self._time(step)
        for j, name in enumerate(names):
            self.stream.log(f"world/plan/{name}",
                            rr.LineStrips3D([plan[:, j]], colors=[[230, 60, 40]], radii=0.01))
            if elites is not None and len(elites):
                k = len(elites)
                alpha = np.linspace(160, 30, k).astype(np.uint8)  # best plans most opaque
                colors = np.stack([np.full(k, 60), np.full(k, 120), np.full(k, 230), alpha], 1)
                self.stream.log(f"world/elites/{name}",
                                rr.LineStrips3D(list(elites[:, :, j]), colors=colors, radii=0.004))

    def log_scalars(self, step: int, **values: float) -> None:
        """``predicted_reward=..., actual_reward=..., predicted_value=...`` -> ``plots/...``."""
        self._time(step)
        for name, value in values.items():
            kind, _, which = name.rpartition("_")
            path = f"plots/{which}/{kind}" if kind else f"plots/{name}"
            self.stream.log(path, rr.Scalars(float(value)))

    def close(self) -> None:
        self.stream.flush()
        self.stream.disconnect()


def entity_paths(path: str) -> list[str]:
    """Entity paths stored in an ``.rrd`` file (for tests and sanity checks)."""
    from rerun.chunk import RrdReader

    return RrdReader(path).store().schema().entity_paths()
