import copy

import pytest
import torch
from torch.distributions import Independent, OneHotCategorical, kl_divergence

from simdist.modules import Actor, DreamerWorldModel, ScalarHead
from simdist.objectives import DreamerActorCriticLoss, DreamerWorldModelLoss, balanced_kl
from tests.synthetic import linear_system_batch


def _teacher(seed=0):
    torch.manual_seed(seed)
    return DreamerWorldModel.teacher(state_dim=4, action_dim=2, size="tiny")


def test_balanced_kl_matches_torch_distributions_with_free_nats():
    rssm = _teacher().rssm
    post, prior = torch.randn(6, 4, 4), torch.randn(6, 4, 4)
    dist = lambda l: Independent(OneHotCategorical(probs=rssm.log_probs(l).exp()), 1)  # noqa: E731
    kl = kl_divergence(dist(post), dist(prior))
    for free in (0.0, 0.5, 100.0):
        expected = 0.8 * kl.clamp_min(free) + 0.2 * kl.clamp_min(free)
        torch.testing.assert_close(balanced_kl(rssm, post, prior, 0.8, free), expected)
    # balancing splits gradients: 0.8 of the gradient goes to the prior
    post.requires_grad_(True)
    prior.requires_grad_(True)
    balanced_kl(rssm, post, prior, 0.8, 0.0).sum().backward()
    post_grad, prior_grad = post.grad.clone(), prior.grad.clone()
    post.grad = prior.grad = None
    rssm.kl(post, prior).sum().backward()
    torch.testing.assert_close(post_grad, 0.2 * post.grad)
    torch.testing.assert_close(prior_grad, 0.8 * prior.grad)


def test_world_model_loss_equals_hand_computation():
    wm = _teacher()
    td = linear_system_batch(batch=3, time=5, obs_dim=4)
    loss = DreamerWorldModelLoss(wm, kl_scale=0.5, free_nats=0.0, reward_scale=2.0)
    torch.manual_seed(1)
    out = loss(td.clone())
    torch.manual_seed(1)  # same sampling noise in the manual pass
    states = wm.observe(td["next", "state"], td["action"], td["is_init"].squeeze(-1))
    feats = DreamerWorldModel.features(states)
    recon = 0.5 * ((wm.decode(feats) - td["next", "state"]) ** 2).sum(-1).mean()
    reward = 0.5 * ((wm.reward(feats) - td["next", "reward"]) ** 2).mean()
    kl = wm.rssm.kl(states["posterior_logits"], states["prior_logits"]).mean()
    torch.testing.assert_close(out["loss_reconstruction"], recon)
    torch.testing.assert_close(out["loss_reward"], 2.0 * reward)
    torch.testing.assert_close(out["loss_kl"], 0.5 * kl)


def test_world_model_loss_learns_a_linear_system():
    wm = _teacher()
    loss = DreamerWorldModelLoss(wm)
    opt = torch.optim.Adam(loss.trainable_parameters(), lr=3e-3)
    td = linear_system_batch(batch=32, time=10, obs_dim=4)
    def total():
        out = loss(td.clone())
        return out["loss_reconstruction"] + out["loss_reward"], out
    first = total()[0].item()
    for _ in range(300):
        value, out = total()
        opt.zero_grad()
        (value + out["loss_kl"]).backward()
        opt.step()
    assert total()[0].item() < first / 4, (first, total()[0].item())


def test_actor_critic_never_touches_the_world_model():
    wm = _teacher()
    actor = Actor(wm.rssm.feature_dim, 2, hidden=16, layers=2)
    critic = ScalarHead(wm.rssm.feature_dim, 16)
    loss = DreamerActorCriticLoss(wm, actor, critic, horizon=4)
    td = linear_system_batch(batch=4, time=5, obs_dim=4)
    DreamerWorldModelLoss(wm)(td)  # writes ("posterior", ...)
    before = copy.deepcopy(wm.state_dict())
    opt = torch.optim.Adam(loss.parameters(), lr=1e-2)  # deliberately everything
    for _ in range(3):
        out = loss(td)
        opt.zero_grad()
        (out["loss_actor"] + out["loss_critic"]).backward()
        assert all(p.grad is None for p in wm.parameters())
        assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in actor.parameters())
        opt.step()
        loss.update_target()
    for k, v in wm.state_dict().items():
        assert torch.equal(v, before[k]), k
    assert all(p.requires_grad for p in wm.parameters())  # held out only temporarily


def test_lambda_return_matches_the_recursion():
    from torchrl.objectives.value.functional import td_lambda_return_estimate
    reward, value = torch.randn(2, 5, 1), torch.randn(2, 5, 1)
    gamma, lmbda = 0.9, 0.7
    out = td_lambda_return_estimate(gamma, lmbda, value, reward, torch.zeros_like(reward, dtype=torch.bool))
    expected = torch.zeros_like(reward)
    nxt = value[:, -1]
    for t in reversed(range(5)):
        nxt = reward[:, t] + gamma * ((1 - lmbda) * value[:, t] + lmbda * nxt) if t < 4 \
            else reward[:, t] + gamma * value[:, t]
        expected[:, t] = nxt
    torch.testing.assert_close(out, expected)


def test_bad_inputs_name_the_key():
    wm = _teacher()
    loss = DreamerWorldModelLoss(wm)
    td = linear_system_batch(batch=2, time=4, obs_dim=4)
    with pytest.raises(KeyError, match="no 'is_init'.*InitTracker"):
        loss(td.exclude("is_init"))
    bad = td.clone()
    bad["next", "reward"][0, 1] = float("nan")
    with pytest.raises(ValueError, match="'next', 'reward'.*NaN"):
        loss(bad)
    with pytest.raises(ValueError, match="\\[batch, time\\]"):
        loss(td[:, 0])
    loss.set_keys(observation=("next", "observation"))
    loss(td)  # remapped key works
    with pytest.raises(ValueError, match="not an accepted tensordict key"):
        loss.set_keys(pixels="x")


def test_pixel_dreamer_reconstruction_uses_normalised_uint8_pixels():
    torch.manual_seed(0)
    wm = DreamerWorldModel.pixel_dreamer(action_dim=2, size="tiny")
    td = linear_system_batch(batch=2, time=3, obs_dim=4)
    td["next", "pixels"] = torch.randint(0, 256, (2, 3, 64, 64, 3), dtype=torch.uint8)
    loss = DreamerWorldModelLoss(wm)
    loss.set_keys(observation=("next", "pixels"))
    torch.manual_seed(1)
    out = loss(td)
    torch.manual_seed(1)
    states = wm.observe(td["next", "pixels"], td["action"], td["is_init"].squeeze(-1))
    target = td["next", "pixels"].float() / 255 - 0.5
    prediction = wm.decode(DreamerWorldModel.features(states))
    expected = 0.5 * (prediction - target).pow(2).sum((-3, -2, -1)).mean()
    torch.testing.assert_close(out["loss_reconstruction"], expected)


def test_reward_without_the_trailing_one_is_a_clear_error():
    loss = DreamerWorldModelLoss(_teacher())
    td = linear_system_batch(batch=2, time=4, obs_dim=4)
    td["next", "reward"] = td["next", "reward"].squeeze(-1)
    with pytest.raises(ValueError, match="\\('next', 'reward'\\) must have shape \\(2, 4, 1\\).*"
                                         "got \\(2, 4\\): add the trailing 1"):
        loss(td)


@pytest.mark.parametrize("scale", ["0-255", "0-1"])
def test_float_pixels_outside_the_models_units_are_refused(scale):
    torch.manual_seed(0)
    wm = DreamerWorldModel.pixel_dreamer(action_dim=2, size="tiny")
    td = linear_system_batch(batch=2, time=3, obs_dim=4)
    images = torch.randint(0, 256, (2, 3, 64, 64, 3), dtype=torch.uint8)
    td["next", "pixels"] = images.float() if scale == "0-255" else images.float() / 255
    loss = DreamerWorldModelLoss(wm)
    loss.set_keys(observation=("next", "pixels"))
    with pytest.raises(ValueError, match="float \\('next', 'pixels'\\) must lie in \\[-0.5, 0.5\\]"):
        loss(td)
    td["next", "pixels"] = images.float() / 255 - 0.5  # the models' own units: accepted
    loss(td)
    td["next", "pixels"] = images.long()
    with pytest.raises(TypeError, match="must be uint8 images"):
        loss(td)


def test_state_recon_reconstructs_the_privileged_state_from_pixels():
    from tensordict import TensorDict
    torch.manual_seed(0)
    wm = DreamerWorldModel.pixel_state_recon(action_dim=1, state_dim=5, size="tiny")
    td = TensorDict({"action": torch.zeros(2, 3, 1),
                     "is_init": torch.zeros(2, 3, 1, dtype=torch.bool),
                     "next": {"pixels": torch.randint(0, 255, (2, 3, 64, 64, 3),
                                                      dtype=torch.uint8),
                              "state": torch.randn(2, 3, 5),
                              "reward": torch.zeros(2, 3, 1)}}, [2, 3])
    loss = DreamerWorldModelLoss(wm)
    loss.set_keys(observation=("next", "pixels"), reconstruction=("next", "state"))
    torch.manual_seed(1)
    posterior = td.clone()
    out = loss(posterior)  # also writes the (detached) posterior states it decoded
    # by hand: the decoder of those posterior features against the state, 0.5 * sum, mean
    features = torch.cat([posterior["posterior", "belief"], posterior["posterior", "stoch"]], -1)
    expected = 0.5 * (wm.decode(features) - td["next", "state"]).pow(2).sum(-1).mean()
    torch.testing.assert_close(out["loss_reconstruction"], expected)
    # a decoder of the image cannot be trained against a state: refused, not broadcast
    pixel = DreamerWorldModelLoss(DreamerWorldModel.pixel_dreamer(action_dim=1, size="tiny"))
    pixel.set_keys(observation=("next", "pixels"), reconstruction=("next", "state"))
    with pytest.raises(ValueError, match="reconstruction target"):
        pixel(td.clone())


def test_actor_input_noise_reads_latents_with_the_stated_noise_and_zero_changes_nothing():
    wm = _teacher()
    td = linear_system_batch(batch=16, time=8, obs_dim=4)
    DreamerWorldModelLoss(wm)(td)  # writes ("posterior", ...)

    def run(noise):
        torch.manual_seed(1)
        actor = Actor(wm.rssm.feature_dim, 2, hidden=16, layers=2)
        critic = ScalarHead(wm.rssm.feature_dim, 16)
        loss = DreamerActorCriticLoss(wm, actor, critic, horizon=2, actor_input_noise=noise)
        reads, original = [], actor.distribution
        actor.distribution = lambda features: (reads.append(features.detach()),
                                               original(features))[1]
        torch.manual_seed(2)
        return loss(td), reads

    (plain, plain_reads), (default, _) = run(0.0), run(0.0)
    assert torch.equal(plain["loss_actor"], default["loss_actor"])
    noisy, noisy_reads = run(0.5)
    start = plain_reads[0]  # the posterior features every rollout starts from
    error = noisy_reads[0] - start
    spread = start.std(0)
    live = spread > 1e-3  # features that vary across the starts
    ratio = error[:, live].std(0) / (0.5 * spread[live])
    assert 0.7 < ratio.mean() < 1.3  # 128 starts: the noise has the stated size
    if (~live).any():  # a constant feature gets (almost) no noise
        assert error[:, ~live].abs().max() < 1e-3 * 0.5 * 4 + 1e-6
    assert not torch.equal(noisy["loss_actor"], plain["loss_actor"])
    with pytest.raises(ValueError, match="actor_input_noise must be >= 0"):
        DreamerActorCriticLoss(wm, Actor(wm.rssm.feature_dim, 2, hidden=16, layers=2),
                               ScalarHead(wm.rssm.feature_dim, 16), actor_input_noise=-0.1)


def _posterior_batch(wm, batch=8):
    td = linear_system_batch(batch=batch, time=6, obs_dim=4)
    DreamerWorldModelLoss(wm)(td)  # writes ("posterior", ...)
    return td


def _actor_grads(loss, td, seed=3):
    torch.manual_seed(seed)
    loss.actor.zero_grad()
    out = loss(td)
    out["loss_actor"].backward()
    return out, [p.grad.clone() for p in loss.actor.parameters()]


@pytest.mark.parametrize("distribution", ["tanh_normal", "trunc_normal"])
def test_reinforce_takes_no_gradient_through_the_model_and_dynamics_does(distribution,
                                                                         monkeypatch):
    """Cutting the model's dependence on the action's gradient leaves the score-function
    gradient unchanged and changes the backpropagated one; the model gets no gradient."""
    wm = _teacher()
    td = _posterior_batch(wm)
    for gradient, unchanged in (("reinforce", True), ("dynamics", False)):
        torch.manual_seed(1)
        actor = Actor(wm.rssm.feature_dim, 2, hidden=16, layers=2, distribution=distribution)
        loss = DreamerActorCriticLoss(wm, actor, ScalarHead(wm.rssm.feature_dim, 16),
                                      horizon=3, entropy_coeff=0.0, actor_gradient=gradient)
        out, through = _actor_grads(loss, td)
        assert torch.isfinite(out["loss_actor"])
        assert all(p.grad is None for p in wm.parameters())
        prior_step = wm.rssm.prior_step
        monkeypatch.setattr(wm.rssm, "prior_step",
                            lambda state, action: prior_step(state, action.detach()))
        _, cut = _actor_grads(loss, td)
        monkeypatch.undo()
        same = all(torch.allclose(a, b) for a, b in zip(through, cut))
        assert same is unchanged, gradient
        assert any(g.abs().sum() > 0 for g in through)


def test_reinforce_loss_is_the_score_function_of_the_advantage():
    """Horizon 1 by hand: ``-(log pi(a|z0) * sg(r + gamma V'(z1) - V(z0))).mean()``."""
    wm = _teacher()
    td = _posterior_batch(wm, batch=4)
    torch.manual_seed(1)
    actor = Actor(wm.rssm.feature_dim, 2, hidden=16, layers=2, distribution="trunc_normal")
    critic = ScalarHead(wm.rssm.feature_dim, 16)
    loss = DreamerActorCriticLoss(wm, actor, critic, horizon=1, gamma=0.9,
                                  entropy_coeff=0.0, actor_gradient="reinforce")
    seen = {}
    head = wm.reward_head

    class Spy(torch.nn.Module):  # records the imagined features the reward reads
        def forward(self, features):
            seen["z1"] = features.detach()
            return head(features)

    wm.reward_head = Spy()
    torch.manual_seed(5)
    out = loss(td)
    wm.reward_head = head
    z0 = torch.cat([td["posterior", "belief"], td["posterior", "stoch"]], -1).flatten(0, -2)
    z1 = seen["z1"]                                       # [N, 1, F]
    # the action the loss drew: replay its random stream
    torch.manual_seed(5)
    action = actor.distribution(z0).rsample()
    ret = wm.reward(z1)[:, 0] + 0.9 * loss.target_critic(z1)[:, 0]
    advantage = (ret - critic(z0)).detach()
    log_prob = actor.distribution(z0).log_prob(action).reshape(advantage.shape)
    expected = -(log_prob * advantage).mean()
    torch.testing.assert_close(out["loss_actor"], expected)
    torch.testing.assert_close(out["advantage"], advantage.abs().mean())


def test_reinforce_finds_the_better_action_without_a_model_gradient(monkeypatch):
    """A model whose imagined reward is ``-(a - 0.5)^2`` of the action taken, with no
    gradient from reward to action: the score-function actor still moves its mode to 0.5."""
    wm = _teacher()
    td = _posterior_batch(wm)
    rssm = wm.rssm

    def prior_step(state, action):  # the belief carries the action, detached
        belief = torch.zeros_like(state.belief)
        belief[..., :2] = action.detach()
        return belief, torch.zeros(*belief.shape[:-1], rssm.stoch, rssm.classes)

    class Reward(torch.nn.Module):
        def forward(self, features):
            return -(features[..., :1] - 0.5).pow(2)

    monkeypatch.setattr(rssm, "prior_step", prior_step)
    wm.reward_head = Reward()
    torch.manual_seed(0)
    actor = Actor(wm.rssm.feature_dim, 2, hidden=16, layers=2, distribution="trunc_normal")
    critic = ScalarHead(wm.rssm.feature_dim, 16)
    for p in critic.parameters():  # V = 0: the advantage is the reward itself
        p.data.zero_()
    loss = DreamerActorCriticLoss(wm, actor, critic, horizon=1, actor_gradient="reinforce")
    starts = td["posterior", "belief"].flatten(0, -2), td["posterior", "stoch"].flatten(0, -2)

    def mode():
        return actor(torch.cat(starts, -1))[:, 0].mean().item()

    before = mode()
    optim = torch.optim.Adam(actor.parameters(), lr=3e-3)
    for _ in range(300):
        out = loss(td)
        optim.zero_grad()
        out["loss_actor"].backward()
        optim.step()
    assert abs(before - 0.5) > 0.2 and abs(mode() - 0.5) < 0.1, (before, mode())


def test_unknown_actor_gradient_is_refused():
    wm = _teacher()
    with pytest.raises(ValueError, match="unknown actor_gradient 'pathwise'"):
        DreamerActorCriticLoss(wm, Actor(wm.rssm.feature_dim, 2, hidden=16, layers=2),
                               ScalarHead(wm.rssm.feature_dim, 16), actor_gradient="pathwise")
