"""DreamerV3's return normalisation: divide the actor's returns by their recent spread.

An actor trained by backpropagating imagined returns weighs its entropy bonus against the
returns' scale. On a task paying ~1 per step with discount 0.99, lambda-returns are ~10-100,
so a fixed entropy weight (3e-4, DreamerV2/V3) barely counts and the actor turns
deterministic early. DreamerV3 divides the returns by ``max(1, S)``, ``S`` an exponential
moving average of the batch's 95th minus 5th percentile of the returns, which makes the
entropy weight mean the same thing on every task while leaving small returns unscaled
(the floor of 1 keeps noise in sparse-reward tasks from being magnified).
"""

from __future__ import annotations

import torch
from torch import nn


class ReturnScale(nn.Module):
    """Running percentile range of lambda-returns (DreamerV3, "return normalisation").

    Args:
        decay: EMA decay of the percentiles (DreamerV3: 0.99).
        low: lower percentile, as a fraction (0.05).
        high: upper percentile, as a fraction (0.95).
        floor: the scale is never below this (1.0: returns spread less are not magnified).

    Examples:
        >>> scale = ReturnScale()
        >>> scale.update(torch.linspace(0, 40, 101))  # 5th / 95th percentile: 2 and 38
        tensor(36.)
        >>> round(float(scale.update(torch.zeros(10))), 2)  # EMA: 0.99 * 36 + 0.01 * 0
        35.64
        >>> float(ReturnScale().update(torch.linspace(0, 0.5, 11)))  # floor
        1.0
    """

    def __init__(self, decay: float = 0.99, low: float = 0.05, high: float = 0.95,
                 floor: float = 1.0):
        super().__init__()
        if not 0 <= decay < 1:
            raise ValueError(f"decay must be in [0, 1), got {decay}")
        if not 0 <= low < high <= 1:
            raise ValueError(f"need 0 <= low < high <= 1, got low={low}, high={high}")
        if not floor > 0:
            raise ValueError(f"floor must be > 0, got {floor}")
        self.decay, self.floor = decay, floor
        self.register_buffer("quantiles", torch.tensor([low, high]))
        # the running percentiles; ``count`` 0 until the first update sets them outright
        self.register_buffer("low", torch.zeros(()))
        self.register_buffer("high", torch.zeros(()))
        self.register_buffer("count", torch.zeros((), dtype=torch.long))

    @torch.no_grad()
    def update(self, returns: torch.Tensor) -> torch.Tensor:
        """Folds a batch of returns into the running percentiles; returns the new scale."""
        values = returns.detach().flatten().float()
        if values.numel() == 0:
            raise ValueError("ReturnScale.update: no returns")
        if not torch.isfinite(values).all():
            raise FloatingPointError("ReturnScale.update: the returns are not finite; check "
                                     "the learning rates and the reward and value heads")
        low, high = torch.quantile(values, self.quantiles.to(values)).to(self.low)
        # the first batch sets the percentiles outright (weight 1); tensor ops, so no host
        # sync on an accelerator
        weight = torch.where(self.count == 0, 1.0, 1 - self.decay).to(self.low)
        self.low.lerp_(low, weight)
        self.high.lerp_(high, weight)
        self.count += 1
        return self.scale()

    def scale(self) -> torch.Tensor:
        """``max(floor, high - low)``, the divisor of the returns (no gradient)."""
        return (self.high - self.low).clamp(min=self.floor)
