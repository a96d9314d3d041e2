"""Headless rendering set-up: EGL by default, and a clear error when no GL loads."""

from __future__ import annotations

import ctypes.util
import os

# The shared library each headless backend loads (mujoco/PyOpenGL dlopen these at import).
_BACKEND_LIBRARIES = {"egl": "EGL", "osmesa": "OSMesa"}

_FIX = (
    "Fixes: on a headless Linux machine install EGL (Debian/Ubuntu: `apt-get install "
    "libegl1 libgl1 libglvnd0 libegl-mesa0`) and use MUJOCO_GL=egl (the default); or "
    "install OSMesa (`apt-get install libosmesa6`) and set MUJOCO_GL=osmesa; with a "
    "display, MUJOCO_GL=glfw. State-only environments (pixels=False) render nothing."
)


class RenderingUnavailableError(RuntimeError):
    """Raised when MuJoCo cannot create an offscreen GL context.

    Examples:
        >>> err = rendering_error(RuntimeError("no EGL display"))  # what a failed render raises
        >>> isinstance(err, RenderingUnavailableError), isinstance(err, RuntimeError)
        (True, True)
        >>> "(RuntimeError: no EGL display)" in str(err), "MUJOCO_GL=osmesa" in str(err)
        (True, True)
    """


def configure_headless_rendering() -> str | None:
    """Chooses a headless GL backend before ``mujoco``/``dm_control`` are imported.

    Both read ``MUJOCO_GL`` at import time and fail with an opaque ``AttributeError``
    deep inside PyOpenGL when the backend's library is missing, so we check first:
    a user-set backend whose library is missing raises :class:`RenderingUnavailableError`
    naming the fix; when unset, EGL is chosen if present, else OSMesa, else nothing
    (state-only use still works; rendering then fails with the same clear error).

    Returns:
        The backend in force, or ``None``.
    """
    backend = os.environ.get("MUJOCO_GL")
    if backend is None:
        for candidate, library in _BACKEND_LIBRARIES.items():
            if ctypes.util.find_library(library):
                backend = os.environ["MUJOCO_GL"] = candidate
                break
    elif backend in _BACKEND_LIBRARIES and not ctypes.util.find_library(
            _BACKEND_LIBRARIES[backend]):
        raise RenderingUnavailableError(
            f"MUJOCO_GL={backend!r} but lib{_BACKEND_LIBRARIES[backend]} is not installed, "
            f"so MuJoCo cannot even be imported. {_FIX}")
    if backend in _BACKEND_LIBRARIES:
        os.environ.setdefault("PYOPENGL_PLATFORM", backend)
    return backend


def rendering_error(cause: BaseException) -> RenderingUnavailableError:
    """Builds an error that names the fix for a failed render or GL context creation."""
    backend = os.environ.get("MUJOCO_GL", "<unset>")
    return RenderingUnavailableError(
        f"MuJoCo could not render offscreen with MUJOCO_GL={backend!r} "
        f"({type(cause).__name__}: {cause}). {_FIX}")
