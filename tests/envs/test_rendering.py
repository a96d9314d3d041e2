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


def _cartpole_sim(visual):
    from simdist.envs import TargetDomain, get_task
    from simdist.envs.simulation import Simulation
    return Simulation(get_task("cartpole-balance"), TargetDomain(), dynamics=None,
                      visual=visual, pixels=True, image_size=64, camera_id=None, seed=0)


def test_render_configuration_poses_the_world_and_redraws_the_scene():
    import numpy as np

    from simdist.envs import VisualRandomisation
    plain = _cartpole_sim(None)
    upright = plain.render_configuration([0.0, 0.0])
    assert upright.shape == (64, 64, 3) and upright.dtype == np.uint8
    assert np.array_equal(upright, plain.render_configuration([0.0, 0.0]))  # same pose
    assert not np.array_equal(upright, plain.render_configuration([0.5, 0.3]))  # moved
    assert np.allclose(plain.physics.data.qpos[:2], [0.5, 0.3])

    randomised = _cartpole_sim(VisualRandomisation.training())
    first = randomised.render_configuration([0.0, 0.0])
    assert not np.array_equal(first, randomised.render_configuration([0.0, 0.0]))  # new draw
    kept = randomised.render_configuration([0.0, 0.0], redraw=False)
    assert np.array_equal(kept, randomised.render_configuration([0.0, 0.0], redraw=False))


def test_render_configuration_rejects_bad_poses():
    sim = _cartpole_sim(None)
    for bad in ([], [[0.0, 0.0]], [0.0, 0.0, 0.0], [float("nan"), 0.0]):
        with pytest.raises(ValueError, match="qpos"):
            sim.render_configuration(bad)
