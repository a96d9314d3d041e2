"""rerun-sdk recordings of planning episodes: robot, plans in 3-D, executed path, traces.

Headless by default: a recording goes to an ``.rrd`` file that the rerun viewer opens
(``rerun file.rrd``). ``spawn=True`` also starts a local viewer process, listening on
localhost only (see :func:`spawn_viewer`).
"""

from __future__ import annotations

import os

import mujoco
import numpy as np

from simdist.utils.atomic import temp_path_beside
from simdist.utils.lazy import lazy_import

rr = lazy_import("rerun")  # ~0.6 s to import: loaded when a recording starts


class PlanningRecorder:
    """Logs one control step at a time to a rerun recording.

    The recording is written to a hidden temp file beside ``path`` and renamed to
    ``path`` by :meth:`close`, so ``path`` only ever holds a complete recording.

    Entity paths: ``world/robot/geoms`` (MuJoCo geoms as points sized by the geom),
    ``world/robot/<body>`` (key bodies), ``world/plan/<body>`` (the chosen plan, one line
    strip per key body), ``world/elites/<body>`` (top-k sampled plans, faded),
    ``world/executed/<body>`` (the path actually taken), and ``plots/reward/predicted``,
    ``plots/reward/actual``, ``plots/value/predicted`` time series.

    Args:
        path: ``.rrd`` file to write (``None``: no file, e.g. with ``spawn``).
        application_id: rerun application id.
        spawn: also start a local rerun viewer and stream to it.
        port: the spawned viewer's gRPC port (rerun's default, 9876).
        bind: the address the spawned viewer listens on. ``rerun.spawn()`` (rerun-sdk
            0.41) starts ``rerun --port 9876`` whose ``--bind`` defaults to ``0.0.0.0``:
            every network interface, so anyone who can reach the machine could stream
            into the viewer or read the recording. Here the default is ``127.0.0.1``
            (this machine only); widen it (``"0.0.0.0"``) only on a trusted network.

    Examples:
        >>> import tempfile, os
        >>> path = os.path.join(tempfile.mkdtemp(), "demo.rrd")
        >>> rec = PlanningRecorder(path)
        >>> rec.log_scalars(0, predicted_reward=1.0, actual_reward=0.9)
        >>> rec.close(); os.path.getsize(path) > 0
        True
    """

    def __init__(self, path: str | None, application_id: str = "simdist", spawn: bool = False,
                 port: int = 9876, bind: str = "127.0.0.1"):
        self.stream = rr.RecordingStream(application_id)
        # Record into a hidden temp file renamed over ``path`` by close(): a crash never
        # leaves a truncated recording under the final name.
        self._partial = temp_path_beside(path) if path is not None else None
        if self._partial is not None:
            self.stream.save(str(self._partial))
        if spawn:
            spawn_viewer(self.stream, port=port, bind=bind)
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
        """Flushes the recording and moves it to ``path`` (atomically)."""
        self.stream.flush()
        self.stream.disconnect()
        if self._partial is not None:
            os.replace(self._partial, self.path)
            self._partial = None


def spawn_viewer(stream: rr.RecordingStream | None = None, port: int = 9876,
                 bind: str = "127.0.0.1", memory_limit: str = "75%", headless: bool = False,
                 detach_process: bool = True) -> int | None:
    """Starts a rerun viewer listening on ``bind:port`` and connects ``stream`` to it.

    ``rerun.spawn()`` cannot choose the address, and the viewer it starts listens on
    ``0.0.0.0`` (all interfaces); this passes ``--bind`` to the same executable instead,
    so by default nothing is reachable from beyond this machine. Blocks until the viewer
    accepts connections.

    Args:
        stream: recording to stream to the viewer (``None``: only start it).
        port: gRPC port.
        bind: listening address (``"127.0.0.1"``: this machine only).
        memory_limit: the viewer's memory limit (rerun syntax, e.g. ``"75%"``, ``"4GB"``).
        headless: no window (the viewer still serves connections).
        detach_process: let the viewer outlive this process.

    Returns:
        The viewer's pid (``None`` where rerun skips spawning, e.g. under its test mode).
    """
    import rerun_bindings

    if os.environ.get("_RERUN_TEST_FORCE_SAVE") is not None:  # as rerun.spawn does
        return None
    kwargs = {"headless": True} if headless else {}  # older rerun-sdk lacks the argument
    pid = rerun_bindings.spawn(
        port=port, memory_limit=memory_limit, detach_process=detach_process,
        executable_name="rerun", extra_args=["--bind", bind],
        # Tells the viewer it is an app started by an SDK (as rerun.spawn does).
        extra_env=[("RERUN_APP_ONLY", "true")], **kwargs)
    if stream is not None:
        host = "127.0.0.1" if bind in ("0.0.0.0", "::", "127.0.0.1") else bind
        host = f"[{host}]" if ":" in host else host
        stream.connect_grpc(f"rerun+http://{host}:{port}/proxy")
    return pid


def entity_paths(path: str) -> list[str]:
    """Entity paths stored in an ``.rrd`` file (for tests and sanity checks)."""
    from rerun.chunk import RrdReader

    return RrdReader(path).store().schema().entity_paths()
