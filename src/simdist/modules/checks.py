"""Boundary checks that turn silent shape/NaN bugs into errors naming the key."""

from __future__ import annotations

import torch


def check_last_dims(name: str, tensor: torch.Tensor, expected: tuple[int, ...]) -> None:
    """Raises if ``tensor``'s trailing dimensions are not ``expected``."""
    if tuple(tensor.shape[-len(expected):]) != tuple(expected) or tensor.dim() < len(expected):
        raise ValueError(f"{name!r} must end with shape {tuple(expected)}, got "
                         f"{tuple(tensor.shape)}")


def check_finite(name: str, tensor: torch.Tensor) -> None:
    """Raises if ``tensor`` holds NaN or inf (a host sync: use at data boundaries only)."""
    if tensor.device.type == "meta":  # shapes only (device tests): no values to check
        return
    if tensor.is_floating_point() and not torch.isfinite(tensor).all():
        bad = (~torch.isfinite(tensor)).sum().item()
        raise ValueError(f"{name!r} contains {bad} non-finite value(s) (NaN or inf)")
