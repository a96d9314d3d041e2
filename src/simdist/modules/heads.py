"""Prediction heads: reward, value, continue, decoders, the Dreamer actor, the policy prior."""

from __future__ import annotations

import torch
from torch import nn
from torchrl.modules import TanhNormal, TruncatedNormal

from simdist.modules.checks import check_last_dims
from simdist.modules.encoders import mlp


class ScalarHead(nn.Module):
    """MLP to one scalar per input (reward, value, continue logit).

    Examples:
        >>> ScalarHead(6, hidden=8)(torch.zeros(4, 6)).shape
        torch.Size([4, 1])
    """

    def __init__(self, in_dim: int, hidden: int = 200, layers: int = 2,
                 activation: type[nn.Module] = nn.ELU):
        super().__init__()
        self.in_dim = in_dim
        self.net = mlp(in_dim, 1, hidden, layers, activation)

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        x = torch.cat(inputs, -1) if len(inputs) > 1 else inputs[0]
        check_last_dims("head input", x, (self.in_dim,))
        return self.net(x)


class StateDecoder(nn.Module):
    """MLP from model features to a state vector (unit-variance Gaussian mean).

    Examples:
        >>> StateDecoder(6, state_dim=3, hidden=8)(torch.zeros(2, 6)).shape
        torch.Size([2, 3])
    """

    def __init__(self, feature_dim: int, state_dim: int, hidden: int = 400, layers: int = 3):
        super().__init__()
        self.state_dim = state_dim
        self.net = mlp(feature_dim, state_dim, hidden, layers)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return self.net(features)


class PixelDecoder(nn.Module):
    """DreamerV2's transposed-conv decoder to 64x64x3, in ``pixels / 255 - 0.5`` units.

    Examples:
        >>> PixelDecoder(6, depth=4)(torch.zeros(2, 5, 6)).shape
        torch.Size([2, 5, 64, 64, 3])
    """

    def __init__(self, feature_dim: int, depth: int = 32):
        super().__init__()
        self.depth = depth
        self.linear = nn.Linear(feature_dim, 32 * depth)
        self.net = nn.Sequential(
            nn.ConvTranspose2d(32 * depth, 4 * depth, 5, stride=2), nn.ELU(),
            nn.ConvTranspose2d(4 * depth, 2 * depth, 5, stride=2), nn.ELU(),
            nn.ConvTranspose2d(2 * depth, depth, 6, stride=2), nn.ELU(),
            nn.ConvTranspose2d(depth, 3, 6, stride=2),
        )

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        lead = features.shape[:-1]
        x = self.linear(features.reshape(-1, features.shape[-1]))[..., None, None]
        return self.net(x).permute(0, 2, 3, 1).reshape(*lead, 64, 64, 3)


def pixels_to_target(pixels: torch.Tensor) -> torch.Tensor:
    """uint8 pixels to the decoder's ``[-0.5, 0.5]`` units."""
    return pixels.float() / 255.0 - 0.5


class Actor(nn.Module):
    """Dreamer actor: a distribution over actions in [-1, 1].

    Two forms (``distribution``):

    * ``"tanh_normal"`` (DreamerV1's form, without its bound on the mean): a Gaussian
      squashed by ``tanh``. Its pre-tanh mean is unbounded, so once it passes ~3 the
      expected action barely moves with it (d E[a] / d mean ~0.01) and the log-det of the
      squashing drives the entropy far below zero.
    * ``"trunc_normal"`` (DreamerV2's): a Gaussian truncated to [-1, 1] whose mean is
      ``tanh`` of the network's output and whose std is ``2 sigmoid(x / 2) + min_std``.
      Samples are not squashed, so a mean at the bound still explores and still gets a
      gradient (d E[a] / d mean ~0.4 at mean 0.999, std 0.3).

    Examples:
        >>> actor = Actor(6, action_dim=2, hidden=8)
        >>> actor(torch.zeros(3, 6)).shape
        torch.Size([3, 2])
        >>> actor.distribution(torch.zeros(3, 6)).rsample().shape
        torch.Size([3, 2])
        >>> v2 = Actor(6, action_dim=2, hidden=8, distribution="trunc_normal")
        >>> bool(v2.distribution(torch.zeros(3, 6)).rsample().abs().max() <= 1)
        True
    """

    DISTRIBUTIONS = ("tanh_normal", "trunc_normal")

    def __init__(self, feature_dim: int, action_dim: int, hidden: int = 400, layers: int = 4,
                 min_std: float = 0.1, init_std: float = 1.0,
                 distribution: str = "tanh_normal"):
        super().__init__()
        if distribution not in self.DISTRIBUTIONS:
            raise ValueError(f"Actor: unknown distribution {distribution!r}; valid: "
                             f"{list(self.DISTRIBUTIONS)}")
        self.action_dim, self.min_std, self.kind = action_dim, min_std, distribution
        self._init_bias = torch.log(torch.expm1(torch.tensor(init_std)))
        self.net = mlp(feature_dim, 2 * action_dim, hidden, layers)

    def distribution(self, features: torch.Tensor) -> TanhNormal | TruncatedNormal:
        mean, raw_std = self.net(features).chunk(2, -1)
        if self.kind == "trunc_normal":
            std = 2 * torch.sigmoid(raw_std / 2) + self.min_std
            return TruncatedNormal(torch.tanh(mean), std, low=-1.0, high=1.0)
        std = nn.functional.softplus(raw_std + self._init_bias.to(raw_std)) + self.min_std
        # The pre-tanh mean is unbounded: TorchRL's ``upscale`` only acts with
        # ``tanh_loc=True``, so it was never DreamerV1's ``5 * tanh(mean / 5)``. Every
        # figure so far was measured this way; a saturated actor explores only through
        # the collector's noise.
        return TanhNormal(mean, std)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """Deterministic action (the distribution's mode; ``tanh`` of the mean either way)."""
        mean, _ = self.net(features).chunk(2, -1)
        return torch.tanh(mean)


class PolicyPrior(nn.Module):
    """SimDist's policy head: a deterministic action from a latent (BC-trained).

    Outputs ``tanh`` in [-1, 1], or, given ``action_low`` / ``action_high`` (``[A]``
    each, e.g. an env's per-joint bounds), the ``tanh`` mapped affinely onto that box:
    a robot whose joints allow more than 1 (the quadruped's lift joints: up to 1.1) gets
    a prior that can reach what the expert executed there.

    Examples:
        >>> PolicyPrior(16, action_dim=3, hidden=8)(torch.zeros(2, 16)).shape
        torch.Size([2, 3])
        >>> box = PolicyPrior(16, 2, hidden=8, action_low=[-1.0, -0.8], action_high=[1.1, 0.8])
        >>> _ = [p.data.zero_() for p in box.net[-1].parameters()]  # tanh(0) = 0
        >>> box(torch.zeros(1, 16))  # the box's centre
        tensor([[0.0500, 0.0000]], grad_fn=<AddBackward0>)
    """

    def __init__(self, latent_dim: int, action_dim: int, hidden: int = 256, layers: int = 2,
                 activation: type[nn.Module] = nn.SiLU, action_low=None, action_high=None):
        super().__init__()
        self.action_dim = action_dim
        self.net = mlp(latent_dim, action_dim, hidden, layers, activation)
        if (action_low is None) != (action_high is None):
            raise ValueError("PolicyPrior: give both action_low and action_high, or neither")
        if action_low is not None:
            low = torch.as_tensor(action_low, dtype=torch.float32).reshape(-1)
            high = torch.as_tensor(action_high, dtype=torch.float32).reshape(-1)
            if low.shape != (action_dim,) or high.shape != (action_dim,):
                raise ValueError(f"PolicyPrior: action bounds must have {action_dim} entries, "
                                 f"got {tuple(low.shape)} and {tuple(high.shape)}")
            if not (torch.isfinite(low).all() and torch.isfinite(high).all()
                    and (low < high).all()):
                raise ValueError(f"PolicyPrior: action bounds must be finite with low < high, "
                                 f"got {low.tolist()} and {high.tolist()}")
            self.register_buffer("action_low", low)
            self.register_buffer("action_high", high)
        else:
            self.action_low = self.action_high = None

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        action = torch.tanh(self.net(latent))
        if self.action_low is None:
            return action
        return self.action_low + (self.action_high - self.action_low) * (action + 1) / 2
