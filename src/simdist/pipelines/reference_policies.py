"""Policies that act without looking, to say what a return is worth on a task.

On some control-suite tasks doing nothing scores well: on cartpole-balance a zero action
lets the nearly undamped pole fall and swing back past upright again and again, and
dm_control's smooth reward pays for every pass (750 +- 19 over the TWIST recipe's 10
evaluation episodes, above what a 6000-step state Dreamer scores). A table of students
and baselines normalised by their teacher is only readable beside these references, so
the TWIST recipe evaluates both on the Oracle's seeds.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torch import nn


class ReferencePolicy(nn.Module):
    """A blind policy: ``"zero"`` actions, or ``"uniform"`` random actions in
    ``[low, high]`` drawn from torch's global generator (seed it, or evaluate through
    :func:`~simdist.pipelines.evaluate_returns`, which forks and seeds it).

    Args:
        kind: ``"zero"`` or ``"uniform"``.
        action_dim: size of the action.
        low: lower action bound (control suite: -1).
        high: upper action bound (control suite: 1).

    Raises:
        ValueError: an unknown ``kind``, a non-positive ``action_dim`` or ``low >= high``.

    Examples:
        >>> from tensordict import TensorDict
        >>> td = TensorDict({"state": torch.zeros(4, 5)}, [4])
        >>> ReferencePolicy("zero", 1)(td)["action"].abs().sum().item()
        0.0
        >>> a = ReferencePolicy("uniform", 2)(td)["action"]
        >>> a.shape, bool((a.abs() <= 1).all())
        (torch.Size([4, 2]), True)
    """

    KINDS = ("zero", "uniform")

    def __init__(self, kind: str, action_dim: int, low: float = -1.0, high: float = 1.0):
        super().__init__()
        if kind not in self.KINDS:
            raise ValueError(f"unknown reference policy {kind!r}; choose from {self.KINDS}")
        if action_dim < 1 or not low < high:
            raise ValueError(f"need action_dim >= 1 and low < high, got {action_dim}, "
                             f"[{low}, {high}]")
        self.kind, self.action_dim, self.low, self.high = kind, action_dim, low, high

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        shape = (*td.batch_size, self.action_dim)
        if self.kind == "zero":
            action = torch.zeros(shape)
        else:
            action = self.low + (self.high - self.low) * torch.rand(shape)
        return td.set("action", action)
