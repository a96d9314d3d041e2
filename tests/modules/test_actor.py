"""The Dreamer actor's two distributions: densities, bounds, modes and gradients."""

import pytest
import torch
from torch.distributions import Normal

from simdist.modules import Actor


def _actor(kind):
    torch.manual_seed(0)
    return Actor(6, action_dim=2, hidden=8, layers=2, distribution=kind)


def test_trunc_normal_actor_matches_a_hand_written_truncated_density():
    """DreamerV2's form: mean tanh(x), std 2 sigmoid(x / 2) + min_std, truncated to [-1, 1];
    the log-density is the Normal's minus log(Phi(1) - Phi(-1)) per dimension, summed."""
    actor = _actor("trunc_normal")
    features = torch.randn(5, 6)
    raw_mean, raw_std = actor.net(features).chunk(2, -1)
    mean, std = torch.tanh(raw_mean), 2 * torch.sigmoid(raw_std / 2) + actor.min_std
    dist = actor.distribution(features)
    action = dist.sample()
    normal = Normal(mean, std)
    mass = normal.cdf(torch.ones_like(mean)) - normal.cdf(-torch.ones_like(mean))
    reference = (normal.log_prob(action) - mass.log()).sum(-1)
    torch.testing.assert_close(dist.log_prob(action), reference, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(actor(features), mean)  # the deterministic action is the mode


def test_trunc_normal_actor_keeps_exploring_and_learning_at_the_bound():
    """Where the tanh-squashed actor has saturated, the truncated one still spreads its
    samples and still passes a gradient from the expected action to its mean."""
    mean = torch.tensor([0.0, 0.999], requires_grad=True)
    from torchrl.modules import TruncatedNormal
    samples = TruncatedNormal(mean, torch.full((2,), 0.3)).rsample((20000,))
    assert samples.min() >= -1 and samples.max() <= 1
    assert samples[:, 1].std() > 0.1
    samples.mean(0).sum().backward()
    assert mean.grad[0] > 0.9 and mean.grad[1] > 0.25  # tanh-normal at loc 3: ~0.01


@pytest.mark.parametrize("kind", Actor.DISTRIBUTIONS)
def test_either_actor_samples_in_the_box_with_gradients_to_its_weights(kind):
    actor = _actor(kind)
    dist = actor.distribution(torch.randn(64, 6))
    action = dist.rsample()
    assert action.shape == (64, 2) and (action.abs() <= 1).all()
    assert dist.log_prob(action).shape == (64,)
    action.sum().backward()
    assert actor.net[0].weight.grad.abs().sum() > 0


def test_actor_refuses_an_unknown_distribution():
    with pytest.raises(ValueError, match="unknown distribution 'beta'"):
        Actor(6, 2, distribution="beta")
