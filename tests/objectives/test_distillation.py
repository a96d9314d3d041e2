import copy

import torch
from torch.distributions import Independent, OneHotCategorical, kl_divergence

from simdist.modules import Actor, DreamerWorldModel
from simdist.objectives import ImaginedAlignmentLoss, TwistDistillationLoss
from tests.synthetic import linear_system_batch


def _pair(seed=0):
    torch.manual_seed(seed)
    teacher = DreamerWorldModel.teacher(state_dim=4, action_dim=2, size="tiny")
    student = DreamerWorldModel.teacher(state_dim=4, action_dim=2, size="tiny")
    return teacher, student


def _batch():
    td = linear_system_batch(batch=4, time=6, obs_dim=4, boundary=3)
    td["next", "student_view"] = td["next", "state"] * 2.0  # a different "camera"
    return td


def test_distillation_is_exactly_zero_for_a_copy_and_positive_otherwise():
    teacher, student = _pair()
    copy_loss = TwistDistillationLoss(teacher, copy.deepcopy(teacher))
    copy_loss.set_keys(student_observation=("next", "state"))
    assert copy_loss(_batch())["loss_distillation"].item() == 0.0
    loss = TwistDistillationLoss(teacher, student)
    loss.set_keys(student_observation=("next", "student_view"))
    out = loss(_batch())
    assert out["belief_mse"] > 0 and out["prior_kl"] > 0 and out["posterior_kl"] > 0


def test_distillation_terms_equal_references():
    teacher, student = _pair()
    loss = TwistDistillationLoss(teacher, student, belief_weight=0.5, prior_weight=2.0,
                                 posterior_weight=3.0)
    loss.set_keys(student_observation=("next", "student_view"))
    td = _batch()
    torch.manual_seed(5)
    out = loss(td)
    torch.manual_seed(5)
    noise = torch.rand(4, 6, teacher.rssm.stoch, teacher.rssm.classes)
    is_init = td["is_init"].squeeze(-1)
    t = teacher.observe(td["next", "state"], td["action"], is_init, noise=noise)
    s = student.observe(td["next", "student_view"], td["action"], is_init, noise=noise)
    dist = lambda l: Independent(OneHotCategorical(probs=teacher.rssm.log_probs(l).exp()), 1)  # noqa: E731
    prior = kl_divergence(dist(s["prior_logits"]), dist(t["prior_logits"])).mean()
    post = kl_divergence(dist(s["posterior_logits"]), dist(t["posterior_logits"])).mean()
    mse = ((t["belief"] - s["belief"]) ** 2).sum(-1).mean()
    torch.testing.assert_close(out["prior_kl"], prior.detach())
    torch.testing.assert_close(out["posterior_kl"], post.detach())
    torch.testing.assert_close(out["belief_mse"], mse.detach())
    torch.testing.assert_close(out["loss_distillation"], 0.5 * mse + 2.0 * prior + 3.0 * post)


def test_teacher_stays_bit_identical_and_gradient_free():
    teacher, student = _pair()
    actor = Actor(teacher.rssm.feature_dim, 2, hidden=8, layers=1)
    distil = TwistDistillationLoss(teacher, student)
    distil.set_keys(student_observation=("next", "student_view"))
    imagined = ImaginedAlignmentLoss(teacher, student, actor, horizon=3)
    before_t, before_a = copy.deepcopy(teacher.state_dict()), copy.deepcopy(actor.state_dict())
    student_before = copy.deepcopy(student.state_dict())
    # deliberately every parameter, teacher and actor included: none may move
    params = list({id(p): p for p in [*distil.parameters(), *imagined.parameters()]}.values())
    opt = torch.optim.Adam(params, lr=1e-2)
    for _ in range(3):
        td = _batch()
        total = distil(td)["loss_distillation"] + imagined(td)["loss_imagined"]
        opt.zero_grad()
        total.backward()
        assert all(p.grad is None for p in teacher.parameters())
        assert all(p.grad is None for p in actor.parameters())
        opt.step()
    assert all(torch.equal(v, before_t[k]) for k, v in teacher.state_dict().items())
    assert all(torch.equal(v, before_a[k]) for k, v in actor.state_dict().items())
    assert any(not torch.equal(v, student_before[k]) for k, v in student.state_dict().items())
    assert {id(p) for p in distil.trainable_parameters()} == {id(p) for p in student.parameters()}


def test_imagined_alignment_replays_the_teachers_exact_actions(monkeypatch):
    teacher, student = _pair()
    actor = Actor(teacher.rssm.feature_dim, 2, hidden=8, layers=1)
    seen = {"teacher": [], "student": []}
    for name, model in (("teacher", teacher), ("student", student)):
        original = model.rssm.prior_step

        def recording(state, action, _orig=original, _name=name):
            seen[_name].append(action.detach().clone())
            return _orig(state, action)
        monkeypatch.setattr(model.rssm, "prior_step", recording)
    loss = ImaginedAlignmentLoss(teacher, student, actor.forward, horizon=4, action_noise_std=0.3)
    loss.set_keys(student_observation=("next", "student_view"))
    td = _batch()
    loss(td)
    # filtering steps first (T each), then the 4 imagined steps
    t_imagined, s_imagined = seen["teacher"][-4:], seen["student"][-4:]
    for a, b in zip(t_imagined, s_imagined):
        assert torch.equal(a, b)
    # the noise made the actions differ from the actor's own choice
    assert not torch.allclose(t_imagined[0], actor(torch.zeros(1, teacher.rssm.feature_dim)).expand_as(t_imagined[0]))
    assert (t_imagined[0].abs() <= 1).all()


def test_imagined_alignment_zero_for_copy_and_reuses_posteriors():
    teacher, _ = _pair()
    actor = Actor(teacher.rssm.feature_dim, 2, hidden=8, layers=1)
    student = copy.deepcopy(teacher)
    distil = TwistDistillationLoss(teacher, student)
    distil.set_keys(student_observation=("next", "state"))
    imagined = ImaginedAlignmentLoss(teacher, student, actor.forward, horizon=3)
    imagined.set_keys(student_observation=("next", "state"))
    td = _batch()
    distil(td)  # writes ("teacher"|"student", ...) posteriors
    assert ("student", "belief") in td.keys(True)
    assert imagined(td)["loss_imagined"].item() == 0.0
    assert imagined(_batch())["loss_imagined"].item() == 0.0  # filters on its own too


def test_student_float_pixels_in_0_255_are_refused():
    import pytest

    torch.manual_seed(0)
    teacher = DreamerWorldModel.teacher(state_dim=4, action_dim=2, size="tiny")
    student = DreamerWorldModel.student(action_dim=2, size="tiny")
    td = linear_system_batch(batch=2, time=3, obs_dim=4)
    td["next", "pixels"] = torch.randint(0, 256, (2, 3, 64, 64, 3)).float()
    with pytest.raises(ValueError, match="TwistDistillationLoss: float \\('next', 'pixels'\\)"):
        TwistDistillationLoss(teacher, student)(td)


def test_standardised_belief_distance_equals_a_hand_computed_value():
    from simdist.objectives.distillation import belief_distance

    # teacher beliefs over a batch of 2 x 2 steps, 3 dimensions
    teacher = torch.tensor([[[0.0, 0.0, 1.0], [2.0, 0.2, 1.0]],
                            [[0.0, 0.0, 1.0], [2.0, 0.2, 1.0]]])
    student = teacher.clone()
    student[0, 0] = torch.tensor([1.0, 0.1, 1.0])  # errors 1 (dim 0), 0.1 (dim 1)
    student[1, 1, 2] = 3.0  # error 2 in the constant dimension 2
    # variances (population, over the 4 steps): 1, 0.01, 0; mean 1.01 / 3
    # floored at 0.01 x mean: 1, 0.01, 0.01/3 * 1.01; weights = mean / variance
    mean = 1.01 / 3
    weights = [mean / 1.0, mean / 0.01, mean / (0.01 * mean)]  # the last capped at 100
    expected = (1.0 * weights[0] + 0.01 * weights[1] + 4.0 * weights[2]) / 4
    plain = (1.0 + 0.01 + 4.0) / 4
    torch.testing.assert_close(belief_distance(teacher, student), torch.tensor(plain))
    got = belief_distance(teacher, student, standardise=True)
    torch.testing.assert_close(got, torch.tensor(expected))
    assert abs(expected - (0.33667 + 0.33667 + 400.0) / 4) < 1e-4  # by hand: 100.168
    # the weights are constants: d/ds of w (t - s)^2 / 4 = 2 w (s - t) / 4
    student.requires_grad_(True)
    belief_distance(teacher, student, standardise=True).backward()
    torch.testing.assert_close(student.grad[0, 0, 1], torch.tensor(2 * 0.1 * weights[1] / 4))
    # equal variances in every dimension: the plain distance
    same = torch.tensor([[0.0, 0.0], [1.0, 1.0]])
    other = torch.tensor([[0.5, 0.0], [1.0, 0.0]])
    torch.testing.assert_close(belief_distance(same, other, standardise=True),
                               belief_distance(same, other))


def test_standardise_belief_reaches_both_losses_and_is_off_by_default():
    teacher, student = _pair()
    actor = Actor(teacher.rssm.feature_dim, 2, hidden=8, layers=1)
    plain = TwistDistillationLoss(teacher, student)
    std = TwistDistillationLoss(teacher, student, standardise_belief=True)
    assert not plain.standardise_belief
    for loss in (plain, std):
        loss.set_keys(student_observation=("next", "student_view"))
    torch.manual_seed(3)
    a = plain(_batch())
    torch.manual_seed(3)
    b = std(_batch())
    torch.testing.assert_close(a["prior_kl"], b["prior_kl"])
    assert not torch.allclose(a["belief_mse"], b["belief_mse"])
    imagined = ImaginedAlignmentLoss(teacher, student, actor, horizon=3,
                                     standardise_belief=True)
    assert imagined.standardise_belief and not ImaginedAlignmentLoss(
        teacher, student, actor, horizon=3).standardise_belief
    imagined.set_keys(student_observation=("next", "student_view"))
    assert imagined(_batch())["imagined_belief_mse"] > 0


def test_standardised_belief_distance_of_a_constant_batch_is_the_plain_one():
    from simdist.objectives.distillation import belief_distance

    teacher, student = torch.ones(3, 4), torch.zeros(3, 4)
    torch.testing.assert_close(belief_distance(teacher, student, standardise=True),
                               torch.tensor(4.0))
