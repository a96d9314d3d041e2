"""Expert actor and critic: TorchRL SAC networks on the robot observation."""

from __future__ import annotations

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator


def make_actor(obs_dim: int, action_spec, hidden: int = 256, obs_key="observation",
               layer_norm: bool = True):
    """Tanh-Gaussian SAC actor (``observation -> action``) bounded by ``action_spec``
    (``layer_norm``: see :class:`QNetwork`)."""
    action_dim = action_spec.shape[-1]
    net = nn.Sequential(
        # observations mix joint angles, velocities and forces
        nn.LayerNorm(obs_dim) if layer_norm else nn.Identity(),
        MLP(in_features=obs_dim, out_features=2 * action_dim, num_cells=[hidden, hidden],
            activation_class=nn.ELU),
        NormalParamExtractor(scale_mapping="biased_softplus_1.0", scale_lb=1e-3),
    )
    module = TensorDictModule(net, in_keys=[obs_key], out_keys=["loc", "scale"])
    low, high = action_spec.space.low, action_spec.space.high
    return ProbabilisticActor(module, in_keys=["loc", "scale"], spec=action_spec,
                              distribution_class=TanhNormal,
                              distribution_kwargs={"low": low, "high": high},
                              return_log_prob=False)


class QNetwork(nn.Module):
    """``Q(observation, action)``: a layer-normed observation and the action into an ELU MLP.

    Examples:
        >>> q = QNetwork(obs_dim=4, action_dim=2, hidden=8)
        >>> q(torch.zeros(3, 4), torch.zeros(3, 2)).shape
        torch.Size([3, 1])
    """

    def __init__(self, obs_dim: int, action_dim: int, hidden: int = 256,
                 layer_norm: bool = True):
        super().__init__()
        # LayerNorm over a handful of heterogeneous features (cartpole's 5-d state) erases
        # each sample's mean and scale, two of its five degrees of freedom: measured, SAC
        # with it does not learn cartpole-balance (docs/findings.md); the quadruped's
        # ~70-d observation keeps it (the committed expert was trained with it)
        self.norm = nn.LayerNorm(obs_dim) if layer_norm else nn.Identity()
        self.net = MLP(in_features=obs_dim + action_dim, out_features=1,
                       num_cells=[hidden, hidden], activation_class=nn.ELU)

    def forward(self, observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([self.norm(observation), action], -1))


def make_critic(obs_dim: int, action_dim: int, hidden: int = 256, obs_key="observation",
                layer_norm: bool = True):
    """``Q(observation, action)`` as a TorchRL ``ValueOperator`` (``layer_norm``: see
    :class:`QNetwork`)."""
    return ValueOperator(QNetwork(obs_dim, action_dim, hidden, layer_norm),
                         in_keys=[obs_key, "action"])
