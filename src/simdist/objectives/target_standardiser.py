"""Running per-dimension standardisation of a regression target.

A decoder that reconstructs a vector with a summed squared error weighs each dimension by
its variance. Dreamer State Recon.'s target on cartpole is ``[x, cos, sin, v, omega]``
with variances ~1.4 / .5 / .5 / .9 / 25 on random-action episodes: the angular velocity
carries ~90% of the loss and the pole's lean (``sin``) ~2%, so the ELBO barely asks the
latent for the lean. Standardising each dimension by its running mean and standard
deviation gives every dimension the same weight (docs/findings.md, "A standardised
state target for Dreamer State Recon.").
"""

from __future__ import annotations

import torch
from torch import nn


class TargetStandardiser(nn.Module):
    """Exponential moving mean and variance of a target's last dimension.

    The first batch sets the statistics outright; later batches move them by
    ``1 - decay``. :meth:`__call__` standardises with the statistics *after* folding the
    batch in (no gradient through them); the buffers travel with ``state_dict``, so a
    resumed run standardises as the interrupted one did.

    Args:
        dim: size of the target's last dimension.
        decay: EMA decay of the statistics.
        min_std: standard deviations are floored here, so a constant dimension is not
            divided by zero.

    Examples:
        >>> standardise = TargetStandardiser(2)
        >>> x = torch.tensor([[0.0, 10.0], [2.0, 30.0]])
        >>> standardise(x)  # mean [1, 20], std [1, 10] (population std)
        tensor([[-1., -1.],
                [ 1.,  1.]])
        >>> standardise.mean, standardise.std()
        (tensor([ 1., 20.]), tensor([ 1., 10.]))
    """

    def __init__(self, dim: int, decay: float = 0.99, min_std: float = 1e-2):
        super().__init__()
        if dim < 1:
            raise ValueError(f"dim must be >= 1, got {dim}")
        if not 0 <= decay < 1:
            raise ValueError(f"decay must be in [0, 1), got {decay}")
        if not min_std > 0:
            raise ValueError(f"min_std must be > 0, got {min_std}")
        self.decay, self.min_std = decay, min_std
        self.register_buffer("mean", torch.zeros(dim))
        self.register_buffer("var", torch.ones(dim))
        self.register_buffer("count", torch.zeros((), dtype=torch.long))

    @torch.no_grad()
    def update(self, target: torch.Tensor) -> None:
        """Folds a batch (any leading shape, last dimension ``dim``) into the statistics."""
        if target.shape[-1] != self.mean.shape[0]:
            raise ValueError(f"TargetStandardiser: expected a last dimension of "
                             f"{self.mean.shape[0]}, got shape {tuple(target.shape)}")
        values = target.detach().reshape(-1, target.shape[-1]).to(self.mean)
        if not torch.isfinite(values).all():
            raise FloatingPointError("TargetStandardiser.update: the target is not finite")
        mean, var = values.mean(0), values.var(0, unbiased=False)
        # the first batch sets the statistics outright; tensor ops: no host sync on a GPU
        weight = torch.where(self.count == 0, 1.0, 1 - self.decay).to(self.mean)
        # the variance around the new mean: the batch's spread plus its mean's shift
        new_mean = self.mean.lerp(mean, weight)
        old_spread = self.var + (self.mean - new_mean).pow(2)
        new_spread = var + (mean - new_mean).pow(2)
        self.var.copy_(old_spread.lerp(new_spread, weight))
        self.mean.copy_(new_mean)
        self.count += 1

    def std(self) -> torch.Tensor:
        return self.var.sqrt().clamp_min(self.min_std)

    def forward(self, target: torch.Tensor, update: bool = True) -> torch.Tensor:
        """``(target - mean) / std``, folding ``target`` into the statistics first unless
        ``update=False``."""
        if update:
            self.update(target)
        return (target - self.mean) / self.std()
