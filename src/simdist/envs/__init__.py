"""Environments: TorchRL envs on dm_control/MuJoCo with privileged state and pixels.

Examples:
    >>> from simdist.envs import make_env
    >>> env = make_env("quadruped-flat", target="slippery_slope", seed=0)
    >>> sorted(env.observation_spec.keys())
    ['dynamics', 'forward_progress', 'observation', 'state']
"""

from simdist.envs.env import SimDistEnv
from simdist.envs.layout import Layout
from simdist.envs.manipulation import BlockLift, BlockPush, PegInsertion, TabletopTask
from simdist.envs.manipulation_scripts import scripted_policy
from simdist.envs.randomisation import DynamicsParams, DynamicsRandomisation, VisualRandomisation
from simdist.rendering import RenderingUnavailableError
from simdist.envs.targets import PRESETS as TARGETS
from simdist.envs.targets import register_target
from simdist.envs.targets import TargetDomain, describe_ranges, get_target
from simdist.envs.tasks import TASKS, TaskSpec, get_task, register_task
from simdist.envs.textures import ColourBank, TextureBank


def make_env(task: str, **kwargs) -> SimDistEnv:
    """Builds a :class:`SimDistEnv`; see its docstring for the options.

    Examples:
        >>> env = make_env("cheetah-run", pixels=True, image_size=32,
        ...                visual_randomisation=VisualRandomisation.training(), seed=1)
        >>> env.reset()["pixels"].shape
        torch.Size([32, 32, 3])
    """
    return SimDistEnv(task, **kwargs)


__all__ = [
    "SimDistEnv", "make_env", "Layout", "DynamicsParams", "DynamicsRandomisation",
    "VisualRandomisation", "RenderingUnavailableError", "TARGETS", "TargetDomain",
    "describe_ranges", "get_target", "TASKS", "TaskSpec", "get_task", "TextureBank",
    "ColourBank", "register_task", "register_target", "BlockPush", "BlockLift",
    "PegInsertion", "TabletopTask", "scripted_policy",
]
