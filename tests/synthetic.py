"""A small synthetic linear system that losses must learn (fast, CPU, deterministic)."""

import torch
from tensordict import TensorDict


def linear_system_batch(batch=16, time=12, obs_dim=4, action_dim=2, seed=0, boundary=None):
    """``[batch, time]`` slices of ``x' = A x + B a`` with reward ``-|x|^2``.

    ``boundary``: index where a new episode starts inside every slice (``is_init``).
    Actions come from a linear "expert" ``tanh(K x)``, replaced by uniform noise on a
    quarter of the steps (``expert_active`` False there), like a perturbed expert.
    Value label = ``-|x|^2 / (1 - 0.9)``.
    """
    g = torch.Generator().manual_seed(seed)
    A = torch.eye(obs_dim) * 0.9 + 0.05 * torch.randn(obs_dim, obs_dim, generator=g)
    B = 0.5 * torch.randn(obs_dim, action_dim, generator=g)
    x = torch.randn(batch, obs_dim, generator=g)
    K = torch.randn(action_dim, obs_dim, generator=g)
    noise = torch.rand(batch, time, action_dim, generator=g) * 2 - 1
    expert = torch.rand(batch, time, 1, generator=g) > 0.25
    obs, next_obs, rewards, actions = [], [], [], []
    for t in range(time):
        if boundary is not None and t == boundary:
            x = torch.randn(batch, obs_dim, generator=g)
        obs.append(x)
        action = torch.where(expert[:, t], torch.tanh(x @ K.T), noise[:, t])
        actions.append(action)
        x = x @ A.T + action @ B.T
        next_obs.append(x)
        rewards.append(-(x ** 2).sum(-1, keepdim=True))
    obs, next_obs, actions = torch.stack(obs, 1), torch.stack(next_obs, 1), torch.stack(actions, 1)
    is_init = torch.zeros(batch, time, 1, dtype=torch.bool)
    is_init[:, 0] = True
    if boundary is not None:
        is_init[:, boundary] = True
    reward = torch.stack(rewards, 1)
    return TensorDict({
        "observation": obs, "state": obs, "action": actions, "is_init": is_init,
        "value_target": -(obs ** 2).sum(-1, keepdim=True) / 0.1,
        "expert_active": expert,
        "next": {"observation": next_obs, "state": next_obs, "reward": reward,
                 "terminated": torch.zeros(batch, time, 1, dtype=torch.bool)},
    }, [batch, time])


class ScaleDynamics(torch.nn.Module):
    """A custom (swappable) dynamics ``z' = z * scale``: none of ``MLPDynamics``'
    attributes beyond ``action_dim`` and ``latent_dim`` (no ``simnorm_groups``)."""

    def __init__(self, action_dim: int, latent_dim: int = 16):
        super().__init__()
        self.action_dim, self.latent_dim = action_dim, latent_dim
        self.scale = torch.nn.Parameter(torch.ones(latent_dim))

    def forward(self, z, a):
        return z * self.scale
