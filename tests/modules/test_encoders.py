import pytest
import torch

from simdist.modules import HistoryEncoder, PixelEncoder, StateEncoder, simnorm


def test_history_windows_clamp_to_episode_start():
    enc = HistoryEncoder(obs_dim=1, history=3, latent_dim=8, hidden=8)
    obs = torch.arange(8.0).reshape(1, 8, 1)
    is_init = torch.zeros(1, 8, dtype=torch.bool)
    is_init[0, 5] = True
    windows = enc.windows(obs, is_init)[0, :, :, 0]
    expected = torch.tensor([[0, 0, 0], [0, 0, 1], [0, 1, 2], [1, 2, 3], [2, 3, 4],
                             [5, 5, 5], [5, 5, 6], [5, 6, 7]], dtype=torch.float32)
    assert torch.equal(windows, expected)


def test_simnorm_groups_are_distributions():
    z = simnorm(torch.randn(3, 16), groups=4).reshape(3, 4, 4)
    torch.testing.assert_close(z.sum(-1), torch.ones(3, 4))
    assert (z >= 0).all()


@pytest.mark.parametrize("lanes", [0, 16])  # the direct softmax, and the AVX512 short-group path
def test_simnorm_matches_a_softmax_per_group_in_value_and_gradient(monkeypatch, lanes):
    monkeypatch.setattr("simdist.modules.encoders._SHORT_GROUP_LANES", lanes)
    torch.manual_seed(0)
    z = (3 * torch.randn(2, 5, 64)).requires_grad_()
    weights = torch.randn(2, 5, 64)
    expected = torch.softmax(z.detach().reshape(2, 5, 8, 8), -1).reshape(2, 5, 64)
    out = simnorm(z, groups=8)
    torch.testing.assert_close(out, expected, atol=1e-6, rtol=0)
    (out * weights).sum().backward()
    reference = z.detach().clone().requires_grad_()
    (torch.softmax(reference.reshape(2, 5, 8, 8), -1).reshape(2, 5, 64) * weights).sum().backward()
    torch.testing.assert_close(z.grad, reference.grad, atol=1e-6, rtol=0)
    half = simnorm(z.detach().bfloat16(), groups=8)  # promoted: the latent stays float32
    assert half.dtype == torch.float32


def test_encoders_reject_wrong_shapes_and_nan():
    with pytest.raises(ValueError, match="'pixels' must end with shape \\(64, 64, 3\\)"):
        PixelEncoder(depth=4)(torch.zeros(2, 32, 32, 3, dtype=torch.uint8))
    with pytest.raises(ValueError, match="'state' must end with shape \\(5,\\)"):
        StateEncoder(5, 8, 8)(torch.zeros(2, 4))
    enc = HistoryEncoder(obs_dim=2, history=2, latent_dim=8, hidden=8)
    bad = torch.zeros(1, 3, 2)
    bad[0, 1, 0] = float("nan")
    with pytest.raises(ValueError, match="'observation' contains 1 non-finite"):
        enc.encode_sequence(bad, torch.zeros(1, 3, dtype=torch.bool))
    with pytest.raises(ValueError, match="not divisible"):
        HistoryEncoder(obs_dim=2, latent_dim=10, simnorm_groups=4)


def test_pixel_encoder_handles_leading_dims_and_uint8_scaling():
    enc = PixelEncoder(depth=4)
    x = torch.randint(0, 256, (2, 3, 64, 64, 3), dtype=torch.uint8)
    out = enc(x)
    assert out.shape == (2, 3, enc.embed_dim)
    torch.testing.assert_close(out[1, 2], enc(x[1, 2][None])[0])


def test_history_encoder_normalisation_is_fixed_and_standardises_inputs():
    torch.manual_seed(0)
    enc = HistoryEncoder(obs_dim=3, history=2, latent_dim=8, hidden=16, simnorm_groups=None)
    obs = torch.randn(50, 2, 3) * torch.tensor([1.0, 100.0, 0.01]) + 5.0
    mean, std = obs.reshape(-1, 3).mean(0), obs.reshape(-1, 3).std(0)
    enc.set_normalisation(mean, std)
    standardised = HistoryEncoder(obs_dim=3, history=2, latent_dim=8, hidden=16, simnorm_groups=None)
    standardised.net.load_state_dict(enc.net.state_dict())
    torch.testing.assert_close(enc(obs), standardised((obs - mean) / std))
    assert "obs_mean" in enc.state_dict() and all(p.dim() for p in enc.parameters())
    assert not any(p is enc.obs_mean or p is enc.obs_std for p in enc.parameters())
    with pytest.raises(ValueError, match="non-finite"):
        enc.set_normalisation(torch.full((3,), float("nan")), std)


def test_pixel_encoder_options_layer_norm_and_per_image_input_norm():
    torch.manual_seed(0)
    x = torch.randint(0, 180, (3, 64, 64, 3), dtype=torch.uint8)
    enc = PixelEncoder(depth=4, norm="layer", input_norm="image")
    assert sum(isinstance(m, torch.nn.LayerNorm) for m in enc.modules()) == 4
    assert all(c.bias is None for c in enc.modules() if isinstance(c, torch.nn.Conv2d))
    # per-image standardisation: each channel of each image enters the CNN with zero mean
    # and unit std, so a global brightness/contrast change of an image is (nearly) invisible
    seen = []
    enc.net[0].register_forward_hook(lambda m, inp, out: seen.append(inp[0]))
    brighter = (x.float() * 1.2 + 20).round().to(torch.uint8)  # at most 235: no clipping
    enc(x), enc(brighter)
    std, mean = torch.std_mean(seen[0], dim=(2, 3))
    torch.testing.assert_close(mean, torch.zeros_like(mean), atol=1e-4, rtol=0)
    assert ((std - 1).abs() < 0.1).all()
    moved = (seen[1] - seen[0]).abs().mean() / seen[0].abs().mean()
    fixed = (PixelEncoder(depth=4)(brighter) - PixelEncoder(depth=4)(x)).abs()
    assert moved < 0.01 and fixed.max() > 0
    with pytest.raises(ValueError, match="norm"):
        PixelEncoder(depth=4, norm="batch")
    with pytest.raises(ValueError, match="input_norm"):
        PixelEncoder(depth=4, input_norm="dataset")


def test_spatial_softmax_returns_the_coordinates_of_each_channel_peak():
    from simdist.modules.encoders import SpatialSoftmax
    maps = torch.full((2, 3, 5, 9), -1e4)
    peaks = [(0, 0), (4, 8), (2, 6)]  # (row, column) per channel
    for c, (row, col) in enumerate(peaks):
        maps[:, c, row, col] = 0.0
    out = SpatialSoftmax()(maps)
    xs = [-1 + 2 * col / 8 for _, col in peaks]
    ys = [-1 + 2 * row / 4 for row, _ in peaks]
    torch.testing.assert_close(out, torch.tensor([xs + ys] * 2))
    # flat maps: every channel at the centre of the image
    torch.testing.assert_close(SpatialSoftmax()(torch.zeros(1, 2, 4, 4)), torch.zeros(1, 4))


def test_keypoint_encoder_follows_a_moving_object_and_keeps_the_pixel_contract():
    torch.manual_seed(0)
    enc = PixelEncoder(depth=4, norm="layer", input_norm="image", arch="keypoints", keypoints=6)
    assert enc.embed_dim == 12
    x = torch.randint(0, 255, (2, 3, 64, 64, 3), dtype=torch.uint8)
    out = enc(x)
    assert out.shape == (2, 3, 12) and out.abs().max() <= 1.0
    # gradients reach the first convolution (the encoder is trainable end to end)
    out.sum().backward()
    assert enc.net[0].weight.grad.abs().sum() > 0
    # keypoints are coordinates: shifting the whole image right moves their mean x right
    # (the first-layer filters see the same content, one map cell further)
    with torch.no_grad():
        blob = torch.zeros(1, 64, 64, 3, dtype=torch.uint8)
        blob[0, 28:36, 8:16] = 255
        moved = torch.roll(blob, 40, dims=2)
        left, right = enc(blob)[0, :6].mean(), enc(moved)[0, :6].mean()
    assert right > left
    with pytest.raises(ValueError, match="arch"):
        PixelEncoder(depth=4, arch="resnet")
    with pytest.raises(ValueError, match="keypoints"):
        PixelEncoder(depth=4, arch="keypoints", keypoints=0)


def test_history_encoder_ignores_the_inputs_it_is_told_to():
    torch.manual_seed(0)
    enc = HistoryEncoder(obs_dim=5, history=2, latent_dim=8, hidden=16, simnorm_groups=None,
                         ignored_inputs=[1, 3])
    obs = torch.randn(4, 2, 5)
    changed = obs.clone()
    changed[..., [1, 3]] = 100 * torch.randn(4, 2, 2)
    torch.testing.assert_close(enc(changed), enc(obs))
    other = obs.clone()
    other[..., 0] += 1.0  # a read input still matters
    assert not torch.allclose(enc(other), enc(obs))
    # the mask is saved only when inputs are ignored: other state dicts keep their keys
    plain = HistoryEncoder(5, 2, 8, 16, simnorm_groups=None)
    assert set(enc.state_dict()) == set(plain.state_dict()) | {"input_mask"}
    with pytest.raises(RuntimeError, match="input_mask"):  # a reader without the mask refuses
        plain.load_state_dict(enc.state_dict())


@pytest.mark.parametrize("ignored, message", [([5], r"indices in \[0, 5\)"), ([-1], "indices"),
                                              ([0, 1, 2, 3, 4], "every observation")])
def test_history_encoder_refuses_impossible_ignored_inputs(ignored, message):
    with pytest.raises(ValueError, match=message):
        HistoryEncoder(obs_dim=5, history=2, latent_dim=8, hidden=16, ignored_inputs=ignored)


def test_history_encoder_reads_each_steps_previous_action_zero_at_an_episode_start():
    enc = HistoryEncoder(obs_dim=2, history=3, latent_dim=8, hidden=16, simnorm_groups=None,
                         action_dim=1)
    assert (enc.input_dim, enc.context) == (3, 4)
    obs = torch.arange(12.0).reshape(1, 6, 2)
    actions = torch.tensor([[10.0, 11.0, 12.0, 13.0, 14.0, 15.0]])[..., None]
    is_init = torch.tensor([[True, False, False, True, False, False]])
    w = enc.windows(obs, is_init, actions)                     # [1, 6, 3, 3]
    # step 2: o_0..o_2 with a_{-1} = 0 (episode start), a_0, a_1
    torch.testing.assert_close(w[0, 2], torch.tensor([[0.0, 1, 0], [2, 3, 10], [4, 5, 11]]))
    # step 4 (second step of the episode that starts at 3): clamped to (o_3, 0), then (o_4, a_3)
    torch.testing.assert_close(w[0, 4], torch.tensor([[6.0, 7, 0], [6, 7, 0], [8, 9, 13]]))
    # the same latents as encoding the windows directly, and the actions matter
    z = enc.encode_sequence(obs, is_init, actions)
    torch.testing.assert_close(z, enc(w))
    assert not torch.allclose(z[0, 2], enc.encode_sequence(obs, is_init, actions + 1)[0, 2])


def test_history_encoder_with_previous_actions_refuses_missing_or_misshapen_actions():
    enc = HistoryEncoder(obs_dim=2, history=2, latent_dim=8, hidden=16, action_dim=3)
    obs, is_init = torch.zeros(2, 5, 2), torch.zeros(2, 5, dtype=torch.bool)
    with pytest.raises(ValueError, match="previous action"):
        enc.encode_sequence(obs, is_init)
    with pytest.raises(ValueError, match="actions must have shape"):
        enc.encode_sequence(obs, is_init, torch.zeros(2, 5, 2))
    with pytest.raises(ValueError, match="NaN or inf|finite"):
        enc.encode_sequence(obs, is_init, torch.full((2, 5, 3), float("nan")))
    with pytest.raises(ValueError, match="action_dim"):
        HistoryEncoder(obs_dim=2, action_dim=-1)
    # an encoder without previous actions ignores them: the same latents either way
    plain = HistoryEncoder(obs_dim=2, history=2, latent_dim=8, hidden=16)
    torch.testing.assert_close(plain.encode_sequence(obs, is_init),
                               plain.encode_sequence(obs, is_init, torch.ones(2, 5, 7)))
