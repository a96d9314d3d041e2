import torch
import pytest
from torch.distributions import Independent, OneHotCategorical, kl_divergence

from simdist.modules import RSSM, DreamerWorldModel, RSSMState


def _rssm(**kw):
    torch.manual_seed(0)
    return RSSM(embed_dim=6, action_dim=2, deter_dim=12, stoch=3, classes=5, hidden_dim=16, **kw)


@pytest.mark.parametrize("unimix", [0.0, 0.01, 0.3])
def test_kl_matches_torch_distributions(unimix):
    rssm = _rssm(unimix=unimix)
    p, q = torch.randn(4, 3, 5), torch.randn(4, 3, 5)
    dist = lambda logits: Independent(OneHotCategorical(probs=rssm.log_probs(logits).exp()), 1)  # noqa: E731
    expected = kl_divergence(dist(p), dist(q))
    torch.testing.assert_close(rssm.kl(p, q), expected, rtol=1e-5, atol=1e-6)
    assert torch.allclose(rssm.kl(p, p), torch.zeros(4), atol=1e-6)


def test_samples_are_one_hot_straight_through_and_follow_shared_noise():
    rssm = _rssm()
    logits = torch.randn(7, 3, 5, requires_grad=True)
    noise = torch.rand(7, 3, 5)
    a, b = rssm.sample(logits, noise), rssm.sample(logits, noise)
    assert torch.equal(a, b)
    hard = a.detach().reshape(7, 3, 5)
    assert torch.equal(hard.sum(-1), torch.ones(7, 3)) and set(hard.unique().tolist()) == {0.0, 1.0}
    a.sum().backward()
    assert logits.grad is not None  # straight-through gradient reaches the logits


def test_sample_frequencies_follow_probabilities():
    rssm = _rssm(unimix=0.0)
    logits = torch.log(torch.tensor([[0.7, 0.2, 0.1, 0.0 + 1e-9, 1e-9]])).expand(3, 5)
    counts = rssm.sample(logits.expand(20000, 3, 5)).detach().reshape(20000, 3, 5).mean(0)
    torch.testing.assert_close(counts[0, :3], torch.tensor([0.7, 0.2, 0.1]), atol=0.02, rtol=0)


def test_episode_boundary_resets_the_recurrent_state():
    rssm = _rssm()
    B, T, k = 2, 8, 5
    embed, action = torch.randn(B, T, 6), torch.randn(B, T, 2)
    noise = torch.rand(B, T, 3, 5)
    is_first = torch.zeros(B, T, dtype=torch.bool)
    is_first[:, k] = True
    crossing = rssm.observe(embed, action, is_first, noise=noise)
    fresh = rssm.observe(embed[:, k:], action[:, k:], is_first[:, k:], noise=noise[:, k:])
    for key in ("belief", "stoch", "posterior_logits", "prior_logits"):
        torch.testing.assert_close(crossing[key][:, k:], fresh[key])
    # without the flag the pre-boundary history changes the post-boundary states
    carried = rssm.observe(embed, action, torch.zeros_like(is_first), noise=noise)
    assert not torch.allclose(carried["belief"][:, k:], fresh["belief"])


def test_imagine_with_given_actions_matches_manual_prior_steps():
    rssm = _rssm()
    state = RSSMState(torch.randn(3, 12), torch.zeros(3, 15))
    actions, noise = torch.randn(3, 4, 2), torch.rand(3, 4, 3, 5)
    out = rssm.imagine(state, actions, noise)
    s = state
    for i in range(4):
        belief, logits = rssm.prior_step(s, actions[:, i])
        s = RSSMState(belief, rssm.sample(logits, noise[:, i]))
        torch.testing.assert_close(out["belief"][:, i], belief)
        torch.testing.assert_close(out["stoch"][:, i], s.stoch)


def test_bad_shapes_name_the_input():
    rssm = _rssm()
    with pytest.raises(ValueError, match="'embed' must end with shape \\(6,\\)"):
        rssm.observe(torch.randn(2, 3, 7), torch.randn(2, 3, 2), torch.zeros(2, 3, dtype=torch.bool))
    with pytest.raises(ValueError, match="'is_init' must have shape"):
        rssm.observe(torch.randn(2, 3, 6), torch.randn(2, 3, 2), torch.zeros(2, 4, dtype=torch.bool))
    with pytest.raises(ValueError, match="unimix"):
        RSSM(6, 2, unimix=1.0)


def test_teacher_and_student_share_the_rssm_class_and_keys():
    teacher = DreamerWorldModel.teacher(state_dim=5, action_dim=2, size="tiny")
    student = DreamerWorldModel.student(action_dim=2, size="tiny")
    assert type(teacher.rssm) is type(student.rssm)
    assert teacher.rssm.feature_dim == student.rssm.feature_dim
    module = teacher.observe_module("state", prefix="teacher")
    assert module.out_keys == [("teacher", "belief"), ("teacher", "stoch"),
                               ("teacher", "prior_logits"), ("teacher", "posterior_logits")]
    from tensordict import TensorDict
    td = TensorDict({"action": torch.zeros(2, 4, 2), "is_init": torch.zeros(2, 4, 1, dtype=torch.bool),
                     "next": {"state": torch.zeros(2, 4, 5)}}, [2, 4])
    module(td)
    assert td["teacher", "belief"].shape == (2, 4, teacher.rssm.deter_dim)
    with pytest.raises(ValueError, match="unknown model size 'huge'"):
        DreamerWorldModel.teacher(5, 2, size="huge")
