import pytest
import torch
from tensordict import TensorDict

from simdist.modules import DreamerWorldModel
from simdist.objectives import DreamerWorldModelLoss, TargetStandardiser


def test_statistics_are_an_ema_of_mean_and_variance_about_the_moving_mean():
    torch.manual_seed(0)
    first = torch.randn(500, 3) * torch.tensor([1.0, 5.0, 0.1]) + torch.tensor([0.0, 2.0, -1.0])
    second = torch.randn(300, 3) * 2 + 4
    s = TargetStandardiser(3, decay=0.9)
    out = s(first)
    torch.testing.assert_close(s.mean, first.mean(0))
    torch.testing.assert_close(s.var, first.var(0, unbiased=False))
    torch.testing.assert_close(out, (first - first.mean(0)) / first.std(0, unbiased=False))
    s.update(second)
    # by hand: the EMA mean, and the EMA of each batch's mean squared deviation about it
    mean = 0.9 * first.mean(0) + 0.1 * second.mean(0)
    var = (0.9 * (first - mean).pow(2).mean(0) + 0.1 * (second - mean).pow(2).mean(0))
    torch.testing.assert_close(s.mean, mean)
    torch.testing.assert_close(s.var, var)
    assert int(s.count) == 2
    # no update: the statistics stay; a constant dimension is divided by the floor
    before = s.mean.clone()
    s(second, update=False)
    assert torch.equal(s.mean, before)
    flat = TargetStandardiser(1, min_std=0.5)
    torch.testing.assert_close(flat(torch.full((4, 1), 3.0)), torch.zeros(4, 1))
    assert float(flat.std()) == 0.5


def test_bad_targets_and_settings_are_refused():
    with pytest.raises(ValueError, match="last dimension of 3"):
        TargetStandardiser(3)(torch.zeros(4, 2))
    with pytest.raises(FloatingPointError, match="not finite"):
        TargetStandardiser(1)(torch.tensor([[float("inf")]]))
    for kwargs, message in (({"dim": 0}, "dim"), ({"dim": 2, "decay": 1.0}, "decay"),
                            ({"dim": 2, "min_std": 0.0}, "min_std")):
        with pytest.raises(ValueError, match=message):
            TargetStandardiser(**kwargs)


def _state_recon_batch(state):
    b, t = state.shape[:2]
    pixels = torch.randint(0, 255, (b, t, 64, 64, 3), dtype=torch.uint8)
    return TensorDict({"action": torch.zeros(b, t, 1),
                       "is_init": torch.zeros(b, t, 1, dtype=torch.bool),
                       "next": {"pixels": pixels, "state": state,
                                "reward": torch.zeros(b, t, 1)}}, [b, t])


def test_the_reconstruction_loss_weighs_each_standardised_dimension_the_same():
    """A State Recon. world model whose decoder predicts a constant: the raw loss is the
    targets' summed squared error (dominated by the wide dimension), the standardised one
    is computed on (target - mean) / std of the batch, i.e. each dimension counts ~1."""
    torch.manual_seed(0)
    state = torch.randn(4, 6, 2) * torch.tensor([0.1, 10.0])
    wm = DreamerWorldModel.pixel_state_recon(1, 2, size="tiny")
    for p in wm.decoder.parameters():
        torch.nn.init.zeros_(p)  # predicts 0 everywhere
    raw = DreamerWorldModelLoss(wm)
    raw.set_keys(observation=("next", "pixels"), reconstruction=("next", "state"))
    std = DreamerWorldModelLoss(wm, reconstruction_standardiser=TargetStandardiser(2))
    std.set_keys(observation=("next", "pixels"), reconstruction=("next", "state"))
    expected_raw = 0.5 * state.pow(2).sum(-1).mean()
    z = (state - state.reshape(-1, 2).mean(0)) / state.reshape(-1, 2).std(0, unbiased=False)
    expected_std = 0.5 * z.pow(2).sum(-1).mean()  # = 0.5 * 2 dimensions
    torch.testing.assert_close(raw(_state_recon_batch(state))["loss_reconstruction"],
                               expected_raw)
    torch.testing.assert_close(std(_state_recon_batch(state))["loss_reconstruction"],
                               expected_std)
    assert float(expected_std) == pytest.approx(1.0, rel=1e-5)


def test_an_image_decoder_refuses_the_standardiser():
    wm = DreamerWorldModel.pixel_dreamer(1, size="tiny")
    loss = DreamerWorldModelLoss(wm, reconstruction_standardiser=TargetStandardiser(3))
    loss.set_keys(observation=("next", "pixels"))
    with pytest.raises(ValueError, match="reconstructs images"):
        loss(_state_recon_batch(torch.zeros(2, 3, 5)))
