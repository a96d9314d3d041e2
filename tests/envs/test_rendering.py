import ctypes.util
import os
import subprocess
import sys

import pytest


@pytest.mark.skipif(ctypes.util.find_library("OSMesa") is not None, reason="OSMesa installed")
def test_missing_gl_backend_names_the_fix():
    env = {**os.environ, "MUJOCO_GL": "osmesa"}
    env.pop("PYOPENGL_PLATFORM", None)
    proc = subprocess.run([sys.executable, "-c", "import simdist"], env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0
    assert "RenderingUnavailableError" in proc.stderr
    assert "apt-get install libosmesa6" in proc.stderr


def test_egl_is_the_default_backend():
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    code = "import simdist, os; print(os.environ['MUJOCO_GL'])"
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, timeout=120)
    assert proc.stdout.strip() == "egl"
