"""Per-dimension action bounds from a TorchRL action spec, for the agents' ``policy(...)``."""

from __future__ import annotations

import torch
from torchrl.data import Composite, TensorSpec


def action_bounds(action_spec: TensorSpec) -> tuple[torch.Tensor, torch.Tensor]:
    """``(low, high)`` of one action, ``[A]`` each, from a TorchRL action spec.

    Accepts what ``env.action_spec`` gives: a ``Bounded`` spec for one env (``[A]``) or a
    batched one (``[B, A]``, every env with the same bounds), or a ``Composite`` holding an
    ``"action"`` entry.

    Raises:
        ValueError: the spec has no finite bounds (e.g. ``Unbounded``) or its batched
            rows disagree (one planner plans within one box).

    Examples:
        >>> from torchrl.data import Bounded
        >>> action_bounds(Bounded(-torch.ones(4, 2), torch.ones(4, 2), (4, 2)))
        (tensor([-1., -1.]), tensor([1., 1.]))
    """
    if isinstance(action_spec, Composite):
        if "action" not in action_spec.keys():
            raise ValueError(f"the Composite action spec has no 'action' entry; keys: "
                             f"{sorted(map(str, action_spec.keys()))}")
        action_spec = action_spec["action"]
    space = getattr(action_spec, "space", None)
    low, high = getattr(space, "low", None), getattr(space, "high", None)
    if not (isinstance(low, torch.Tensor) and isinstance(high, torch.Tensor)):
        raise ValueError(f"action_spec must be bounded (e.g. torchrl.data.Bounded), got "
                         f"{type(action_spec).__name__}")
    low, high = low.detach().float().cpu(), high.detach().float().cpu()
    if low.dim() == 0:
        raise ValueError("action_spec must have an action dimension, got a scalar spec")
    rows_low, rows_high = low.reshape(-1, low.shape[-1]), high.reshape(-1, high.shape[-1])
    if not (torch.equal(rows_low, rows_low[:1].expand_as(rows_low))
            and torch.equal(rows_high, rows_high[:1].expand_as(rows_high))):
        raise ValueError("the batched action_spec has different bounds per env; pass "
                         "action_low/action_high for one of them")
    low, high = rows_low[0].clone(), rows_high[0].clone()
    # Unbounded specs report +-float32 max (3.4e38) rather than inf.
    if not (torch.isfinite(low).all() and torch.isfinite(high).all()) or \
            (low.abs().max() > 1e30) or (high.abs().max() > 1e30):
        raise ValueError(f"action_spec must be bounded (e.g. torchrl.data.Bounded), got "
                         f"bounds {low} and {high} ({type(action_spec).__name__})")
    return low, high
