"""Shared test set-up: headless GL before anything imports dm_control, one torch thread."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import torch  # noqa: E402

import simdist  # noqa: E402,F401  (configures rendering)

torch.set_num_threads(1)
