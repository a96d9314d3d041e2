import numpy as np
import pytest
import torch

from simdist.modules import Actor, ScalarHead
from simdist.objectives import DreamerActorCriticLoss, DreamerWorldModelLoss
from simdist.objectives.return_scale import ReturnScale
from tests.objectives.test_dreamer import _teacher
from tests.synthetic import linear_system_batch


def test_scale_is_an_ema_of_the_percentile_range_with_a_floor():
    torch.manual_seed(0)
    first, second = 30 * torch.rand(2000), 5 * torch.randn(1000) + 50
    scale = ReturnScale(decay=0.9)
    range_of = lambda x: np.percentile(x.numpy(), 95) - np.percentile(x.numpy(), 5)  # noqa: E731
    assert float(scale.update(first)) == pytest.approx(range_of(first), rel=1e-5)
    # the EMA of each percentile, by hand: 0.9 old + 0.1 new
    low = 0.9 * np.percentile(first.numpy(), 5) + 0.1 * np.percentile(second.numpy(), 5)
    high = 0.9 * np.percentile(first.numpy(), 95) + 0.1 * np.percentile(second.numpy(), 95)
    assert float(scale.update(second)) == pytest.approx(high - low, rel=1e-5)
    assert int(scale.count) == 2
    tight = ReturnScale()
    assert float(tight.update(torch.full((50,), 7.0))) == 1.0  # no spread: the floor
    assert float(ReturnScale(floor=0.5).update(torch.linspace(0, 0.1, 101))) == 0.5


def test_bad_returns_and_settings_are_refused():
    with pytest.raises(FloatingPointError, match="not finite"):
        ReturnScale().update(torch.tensor([1.0, float("nan")]))
    with pytest.raises(ValueError, match="no returns"):
        ReturnScale().update(torch.zeros(0))
    for kwargs, message in (({"decay": 1.0}, "decay"), ({"low": 0.9, "high": 0.1}, "low"),
                            ({"floor": 0.0}, "floor")):
        with pytest.raises(ValueError, match=message):
            ReturnScale(**kwargs)


def test_the_actor_gradient_of_the_returns_is_divided_by_the_scale_and_the_critic_not():
    """With no entropy bonus, the scaled actor loss's gradient is the unscaled one divided
    by the scale reported; the critic's loss is unchanged; the entropy's gradient is not
    divided (DreamerV3: the returns are normalised, not the whole objective)."""
    wm = _teacher()
    td = linear_system_batch(batch=8, time=6, obs_dim=4)
    DreamerWorldModelLoss(wm)(td)

    def run(scale, entropy_coeff):
        torch.manual_seed(1)
        actor = Actor(wm.rssm.feature_dim, 2, hidden=16, layers=2)
        loss = DreamerActorCriticLoss(wm, actor, ScalarHead(wm.rssm.feature_dim, 16),
                                      horizon=3, entropy_coeff=entropy_coeff,
                                      return_scale=scale)
        torch.manual_seed(2)
        out = loss(td)
        out["loss_actor"].backward()
        return out, [p.grad.clone() for p in actor.parameters()]

    plain, plain_grads = run(None, 0.0)
    scaled, scaled_grads = run(ReturnScale(), 0.0)
    divisor = float(scaled["return_scale"])
    assert divisor > 1  # the imagined returns here spread by more than 1
    assert "return_scale" not in plain.keys()
    assert torch.allclose(scaled["loss_critic"], plain["loss_critic"])
    assert scaled["loss_actor"].item() == pytest.approx(plain["loss_actor"].item() / divisor,
                                                        rel=1e-5)
    for g_scaled, g_plain in zip(scaled_grads, plain_grads):
        assert torch.allclose(g_scaled * divisor, g_plain, rtol=1e-4, atol=1e-6)
    # the entropy bonus keeps its weight: its share of the loss grows by the divisor
    bonus_plain = run(None, 0.1)[0]["loss_actor"] - plain["loss_actor"]
    bonus_scaled = run(ReturnScale(), 0.1)[0]["loss_actor"] - scaled["loss_actor"]
    assert bonus_scaled.item() == pytest.approx(bonus_plain.item(), rel=1e-4)
