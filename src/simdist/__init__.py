"""simdist: world models trained in simulation that transfer to shifted domains.

Implements SimDist (simulation distillation: pretrain a latent world model in sim,
plan with latent MPPI, finetune only the dynamics on target data) and TWIST
(teacher-student world-model distillation from state to pixels) on TorchRL.
"""

from simdist.rendering import configure_headless_rendering

# Must run before dm_control/mujoco pick a GL backend (they read MUJOCO_GL on import).
configure_headless_rendering()

__version__ = "0.1.0"
