"""Headless rendering set-up: EGL by default, and a clear error when no GL loads."""

from __future__ import annotations

import os

_VALID_BACKENDS = ("egl", "osmesa", "glfw")


def configure_headless_rendering() -> str:
    """Defaults ``MUJOCO_GL`` (and ``PYOPENGL_PLATFORM``) to EGL when unset.

    Must run before ``dm_control`` or ``mujoco.egl`` is imported, since both read the
    variables at import time. A value the user already set is respected.

    Returns:
        The backend in force.
    """
    backend = os.environ.setdefault("MUJOCO_GL", "egl")
    if backend in ("egl", "osmesa"):
        os.environ.setdefault("PYOPENGL_PLATFORM", backend)
    return backend


class RenderingUnavailableError(RuntimeError):
    """Raised when MuJoCo cannot create an offscreen GL context."""


def rendering_error(cause: BaseException) -> RenderingUnavailableError:
    """Builds an error that names the fix for a failed GL context creation."""
    backend = os.environ.get("MUJOCO_GL", "<unset>")
    return RenderingUnavailableError(
        f"MuJoCo could not create an offscreen OpenGL context with MUJOCO_GL={backend!r} "
        f"({type(cause).__name__}: {cause}). Pixel observations need a GL backend. Fixes: "
        "on a headless Linux machine install EGL (Debian/Ubuntu: `apt-get install "
        "libegl1 libgl1 libglvnd0` plus Mesa `libegl-mesa0` for software rendering) and "
        "keep MUJOCO_GL=egl; or install OSMesa (`apt-get install libosmesa6`) and set "
        "MUJOCO_GL=osmesa PYOPENGL_PLATFORM=osmesa; with a display, MUJOCO_GL=glfw. "
        "State-only environments (pixels=False) need no GL at all."
    )
