"""Scripted controllers that solve the tabletop tasks from the privileged state.

They prove each task solvable and its success check right (``tests/envs/
test_manipulation.py``), and give a reference any learned policy can be compared with.
Each maps a batch of ``"state"`` vectors (the task's ``state_layout``) to actions, with no
memory: the phase (reach, descend, grasp, lift / push / insert) is read off the state.

Examples:
    >>> import simdist
    >>> from simdist.envs import make_env
    >>> env = make_env("peg-insertion", seed=0)
    >>> td = env.rollout(150, scripted_policy(env))
    >>> bool(td["next", "success"][-1])
    True
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict.nn import TensorDictModule

from simdist.envs.manipulation import CUBE_HALF, INSERT_DEPTH, MAX_STEP

#: Hand heights (m): travelling above everything, and pushing / grasping the cube.
TRAVEL_Z, PUSH_Z, GRASP_Z = 0.13, 0.07, CUBE_HALF + 0.046


def _towards(hand: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The delta action that moves the hand to ``target`` at most one step per axis."""
    return np.clip((target - hand) / MAX_STEP, -1.0, 1.0)


def _travel(hand, goal_xy, goal_z, tolerance=0.01):
    """Rise, move above ``goal_xy``, then go down to ``goal_z``: the target to head for."""
    far = np.linalg.norm(hand[:2] - goal_xy) > tolerance
    if far and hand[2] < TRAVEL_Z - 0.02:
        return np.array([hand[0], hand[1], TRAVEL_Z])
    return np.array([goal_xy[0], goal_xy[1], TRAVEL_Z if far else goal_z])


def push_action(s: dict) -> np.ndarray:
    """Closed jaws as a paddle: behind the cube (seen from the goal), down, then push."""
    hand, cube, goal = s["hand_pos"], s["object_pos"], s["goal"]
    way = goal[:2] - cube[:2]
    u = way / max(np.linalg.norm(way), 1e-6)
    rel = cube[:2] - hand[:2]
    along, lateral = rel @ u, rel - (rel @ u) * u
    behind = cube[:2] - 0.055 * u
    if along > 0.02 and np.linalg.norm(lateral) < 0.015 and hand[2] < PUSH_Z + 0.02:
        # pushing: head for the point that leaves the cube on the goal, steering sideways
        target_xy = goal[:2] - 0.045 * u + 1.5 * lateral
        target = np.array([target_xy[0], target_xy[1], PUSH_Z])
    else:
        target = _travel(hand, behind, PUSH_Z)
    return np.append(_towards(hand, target), 1.0)


def lift_action(s: dict) -> np.ndarray:
    """Open above the cube, down around it, close, then lift."""
    hand, cube, closure = s["hand_pos"], s["object_pos"], float(s["jaws"][0])
    grasp = np.array([cube[0], cube[1], cube[2] - CUBE_HALF + GRASP_Z])
    held = closure > 0.006 and np.linalg.norm(hand - grasp) < 0.02
    if held:
        return np.append(_towards(hand, np.array([cube[0], cube[1], 0.2])), 1.0)
    if np.linalg.norm(hand - grasp) < 0.006:  # in place: close the jaws, hold still
        return np.array([0.0, 0.0, 0.0, 1.0])
    return np.append(_towards(hand, _travel(hand, cube[:2], grasp[2], tolerance=0.005)), -1.0)


def insertion_action(s: dict) -> np.ndarray:
    """Above the hole, aligned to a millimetre, then straight down."""
    hand, tip, hole = s["hand_pos"], s["peg_tip"], s["hole"]
    offset = hand - tip  # the peg hangs below the hand
    aligned = np.abs(tip[:2] - hole[:2]).max() < 0.001
    above = hole[2] + 0.01 + offset[2]
    if not aligned:
        z = max(hand[2], above) if np.abs(tip[:2] - hole[:2]).max() > 0.004 else hand[2]
        target = np.array([hole[0] + offset[0], hole[1] + offset[1], z])
    else:
        target = np.array([hole[0] + offset[0], hole[1] + offset[1],
                           hole[2] - INSERT_DEPTH - 0.005 + offset[2]])
    return _towards(hand, target)


ACTIONS = {"block-push": push_action, "block-lift": lift_action,
           "peg-insertion": insertion_action}


def scripted_policy(env) -> TensorDictModule:
    """The scripted controller of ``env``'s task as a policy reading ``"state"``.

    Raises:
        KeyError: the task has no scripted controller.
    """
    name = env.task_spec.name
    if name not in ACTIONS:
        raise KeyError(f"no scripted controller for {name!r}; scripted: {sorted(ACTIONS)}")
    act, layout = ACTIONS[name], env.state_layout

    def policy(state: torch.Tensor) -> torch.Tensor:
        flat = state.detach().cpu().double().numpy().reshape(-1, layout.size)
        actions = [act({k: v for k, v in layout.split(row).items()}) for row in flat]
        return torch.as_tensor(np.stack(actions), dtype=torch.float32).reshape(
            *state.shape[:-1], -1)

    return TensorDictModule(policy, in_keys=["state"], out_keys=["action"])
