import copy

import pytest
import torch

from simdist.modules import SimDistWorldModel, StateDecoder
from simdist.objectives import DynamicsFinetuneLoss, ProbeLoss, SimDistPretrainLoss
from simdist.objectives.simdist_pretrain import rollout_windows
from tests.synthetic import linear_system_batch


def _model(seed=0):
    torch.manual_seed(seed)
    return SimDistWorldModel.build(obs_dim=4, action_dim=2, size="tiny")


def test_pretrain_terms_equal_hand_computation():
    wm = _model()
    td = linear_system_batch(batch=2, time=5, obs_dim=4)
    td["expert_active"][:, 1] = False
    out = SimDistPretrainLoss(wm, horizon=2, bc_weight=4.0)(td)
    obs, act = td["observation"], td["action"]
    is_init = td["is_init"].squeeze(-1)
    z = wm.encode_sequence(obs, is_init)
    cons, rew, val = [], [], []
    for t in range(3):  # starts 0..T-H-1
        zi = z[:, t]
        rew.append((wm.reward(zi, act[:, t]) - td["next", "reward"][:, t]) ** 2)
        val.append((wm.value(zi) - td["value_target"][:, t]) ** 2)
        for i in range(2):
            zi = wm.next(zi, act[:, t + i])
            cons.append(((zi - z[:, t + i + 1]) ** 2).sum(-1))  # summed over latent dims
            if i < 1:
                rew.append((wm.reward(zi, act[:, t + i + 1]) - td["next", "reward"][:, t + i + 1]) ** 2)
            # the value is regressed up to z^_{t+H}, where the planner reads it
            val.append((wm.value(zi) - td["value_target"][:, t + i + 1]) ** 2)
    expert = td["expert_active"].squeeze(-1)
    bc = ((wm.policy(z) - act) ** 2).mean(-1)[expert].mean()
    torch.testing.assert_close(out["loss_consistency"], torch.stack(cons).mean())
    torch.testing.assert_close(out["loss_reward"], torch.stack(rew).mean())
    torch.testing.assert_close(out["loss_value"], torch.stack(val).mean())
    torch.testing.assert_close(out["loss_bc"], 4.0 * bc)


def test_value_head_is_trained_at_the_planning_horizon():
    # Only the label at t + H differs: the value loss must change (it reaches z^_{t+H}).
    wm = _model()
    td = linear_system_batch(batch=2, time=4, obs_dim=4)
    loss = SimDistPretrainLoss(wm, horizon=3)
    before = loss(td)["loss_value"]
    td["value_target"][:, 3] += 1000.0
    assert loss(td)["loss_value"] > before + 1000.0


def test_rollouts_never_target_across_an_episode_start():
    wm = _model()
    td = linear_system_batch(batch=1, time=6, obs_dim=4, boundary=3)
    is_init = td["is_init"].squeeze(-1)
    z = wm.encode_sequence(td["observation"], is_init)
    _, _, mask = rollout_windows(wm, z, td["action"], is_init, horizon=2)
    # starts 0..3; targets are steps t+1, t+2; step 3 starts a new episode
    expected = torch.tensor([[1, 1], [1, 0], [0, 0], [1, 1]], dtype=torch.float32)
    assert torch.equal(mask[0], expected)
    with pytest.raises(ValueError, match="too short for horizon 6"):
        rollout_windows(wm, z, td["action"], is_init, horizon=6)


def test_pretraining_learns_a_linear_system():
    wm = _model()
    loss = SimDistPretrainLoss(wm, horizon=3)
    opt = torch.optim.Adam(loss.trainable_parameters(), lr=3e-3)
    td = linear_system_batch(batch=32, time=10, obs_dim=4)
    terms = ("loss_reward", "loss_value", "loss_bc")
    first = {k: v.item() for k, v in loss(td).items() if k in terms}
    for _ in range(300):
        out = loss(td)
        total = sum(out[k] for k in out.keys() if k.startswith("loss"))
        opt.zero_grad()
        total.backward()
        opt.step()
    last = {k: v.item() for k, v in loss(td).items() if k in terms}
    for k in terms:  # each supervised term falls at least 3x
        assert last[k] < first[k] / 3, (k, first[k], last[k])
    assert loss(td)["latent_std"] > 1e-3  # the latent did not collapse


def test_finetuning_changes_only_the_dynamics():
    wm = _model()
    loss = DynamicsFinetuneLoss(wm, horizon=3)
    frozen = {name: copy.deepcopy(part.state_dict()) for name, part in wm.parts().items()
              if name != "dynamics"}
    dynamics_before = copy.deepcopy(wm.dynamics.state_dict())
    opt = torch.optim.Adam(wm.parameters(), lr=1e-2)  # deliberately every parameter
    td = linear_system_batch(batch=8, time=8, obs_dim=4, seed=3)
    first = loss(td)["loss_consistency"].item()
    for _ in range(100):
        out = loss(td)
        opt.zero_grad()
        out["loss_consistency"].backward()
        for name, part in wm.parts().items():
            if name != "dynamics":
                assert all(p.grad is None for p in part.parameters()), name
        opt.step()
    for name, state in frozen.items():
        for k, v in getattr(wm, name).state_dict().items():
            assert torch.equal(v, state[k]), (name, k)
    assert any(not torch.equal(v, dynamics_before[k]) for k, v in wm.dynamics.state_dict().items())
    assert loss(td)["loss_consistency"].item() < first / 2


def test_finetune_head_terms_equal_hand_computation():
    wm = _model()
    td = linear_system_batch(batch=2, time=5, obs_dim=4)
    out = DynamicsFinetuneLoss(wm, horizon=2, reward_weight=0.5, value_weight=2.0)(td)
    act, reward = td["action"], td["next", "reward"]
    z = wm.encode_sequence(td["observation"], td["is_init"].squeeze(-1))
    cons, rew, val = [], [], []
    for t in range(3):  # starts 0..T-H-1
        zi = z[:, t]
        for i in range(2):
            zi = wm.next(zi, act[:, t + i])
            cons.append(((zi - z[:, t + i + 1]) ** 2).sum(-1))
            val.append((wm.value(zi) - wm.value(z[:, t + i + 1])) ** 2)  # frozen V, both sides
            if i < 1:  # predicted latents z^_{t+1..t+H-1}, each with its own action
                rew.append((wm.reward(zi, act[:, t + i + 1]) - reward[:, t + i + 1]) ** 2)
    torch.testing.assert_close(out["loss_consistency"], torch.stack(cons).mean())
    torch.testing.assert_close(out["loss_reward"], 0.5 * torch.stack(rew).mean())
    torch.testing.assert_close(out["loss_value"], 2.0 * torch.stack(val).mean())
    torch.testing.assert_close(out["reward_error_on_predictions"], torch.stack(rew).mean())
    reference = DynamicsFinetuneLoss(wm, horizon=2)(td)  # weights 0: consistency alone
    assert sorted(k for k in reference.keys() if k.startswith("loss_")) == ["loss_consistency"]
    torch.testing.assert_close(reference["loss_consistency"], out["loss_consistency"])


def test_slice_errors_and_priority_weights_equal_hand_computation():
    wm = _model()
    td = linear_system_batch(batch=3, time=5, obs_dim=4)
    loss = DynamicsFinetuneLoss(wm, horizon=2)
    z = wm.encode_sequence(td["observation"], td["is_init"].squeeze(-1))
    per_slice = []  # [B] mean over the slice's starts and steps of ||z^ - z||^2
    for b in range(3):
        errors = []
        for t in range(3):
            zi = z[b, t]
            for i in range(2):
                zi = wm.next(zi[None], td["action"][b, t + i][None])[0]
                errors.append(((zi - z[b, t + i + 1]) ** 2).sum())
        per_slice.append(torch.stack(errors).mean())
    per_slice = torch.stack(per_slice)
    out = loss(td)
    torch.testing.assert_close(out["slice_error"], per_slice.detach())
    weight = torch.tensor([1.0, 0.5, 0.25])
    weighted = td.clone()
    weighted["priority_weight"] = weight[:, None, None].expand(3, 5, 1).clone()
    torch.testing.assert_close(loss(weighted)["loss_consistency"],
                               (weight * per_slice).sum() / weight.sum())
    weighted["priority_weight"] = torch.ones(3, 5, 1)  # unit weights: the plain loss
    torch.testing.assert_close(loss(weighted)["loss_consistency"], out["loss_consistency"])
    weighted["priority_weight"][1] = float("nan")
    with pytest.raises(ValueError, match="priority_weight"):
        loss(weighted)
    weighted["priority_weight"] = torch.ones(3, 5, 2)  # two weights per step
    with pytest.raises(ValueError, match=r"\[B, T\]"):
        loss(weighted)


def test_slice_errors_average_only_the_windows_inside_one_episode():
    wm = _model()
    td = linear_system_batch(batch=2, time=6, obs_dim=4, boundary=3)  # an episode starts at 3
    out = DynamicsFinetuneLoss(wm, horizon=2)(td)
    predicted, targets, mask = rollout_windows(
        wm, wm.encode_sequence(td["observation"], td["is_init"].squeeze(-1)), td["action"],
        td["is_init"].squeeze(-1), 2)
    assert 0 < mask.sum() < mask.numel()  # some windows cross the boundary
    error = ((predicted - targets) ** 2).sum(-1)
    by_hand = torch.stack([error[b][mask[b] > 0].mean() for b in range(2)])
    torch.testing.assert_close(out["slice_error"], by_hand.detach())
    weighted = td.clone()
    weight = torch.tensor([1.0, 0.2])
    weighted["priority_weight"] = weight[:, None].expand(2, 6).clone()
    counts = mask.sum((1, 2))
    expected = (weight * by_hand * counts).sum() / (weight * counts).sum()
    torch.testing.assert_close(DynamicsFinetuneLoss(wm, horizon=2)(weighted)["loss_consistency"],
                               expected.detach(), rtol=1e-5, atol=1e-6)


def test_finetuning_through_frozen_heads_changes_only_the_dynamics():
    wm = _model()
    loss = DynamicsFinetuneLoss(wm, horizon=3, reward_weight=1.0, value_weight=1.0)
    frozen = {name: copy.deepcopy(part.state_dict()) for name, part in wm.parts().items()
              if name != "dynamics"}
    opt = torch.optim.Adam(wm.parameters(), lr=1e-2)  # deliberately every parameter
    td = linear_system_batch(batch=8, time=8, obs_dim=4, seed=3)
    first = loss(td)
    for _ in range(100):
        out = loss(td)
        opt.zero_grad()
        sum(v for k, v in out.items() if k.startswith("loss_")).backward()
        assert all(p.grad is not None for p in wm.dynamics.parameters())
        for name, part in wm.parts().items():
            if name != "dynamics":
                assert all(p.grad is None for p in part.parameters()), name
        opt.step()
    for name, state in frozen.items():
        for k, v in getattr(wm, name).state_dict().items():
            assert torch.equal(v, state[k]), (name, k)
    last = loss(td)
    assert last["loss_reward"] < first["loss_reward"]
    # the reward term is what lowered the frozen reward head's error on predictions:
    # consistency alone, same steps from the same model, leaves it higher
    wm_alone = _model()
    alone = DynamicsFinetuneLoss(wm_alone, horizon=3)
    opt = torch.optim.Adam(alone.trainable_parameters(), lr=1e-2)
    for _ in range(100):
        opt.zero_grad()
        alone(td)["loss_consistency"].backward()
        opt.step()
    assert last["reward_error_on_predictions"] < alone(td)["reward_error_on_predictions"]


@pytest.mark.parametrize("kwargs, match", [
    (dict(reward_weight=-1.0), "reward_weight"), (dict(value_weight=float("nan")), "value_weight"),
    (dict(horizon=1, reward_weight=1.0), "horizon >= 2")])
def test_finetune_weights_are_checked(kwargs, match):
    with pytest.raises(ValueError, match=match):
        DynamicsFinetuneLoss(_model(), **kwargs)


def test_probe_trains_only_the_probe():
    wm = _model()
    probe = StateDecoder(wm.latent_dim, 4, hidden=16, layers=2)
    loss = ProbeLoss(wm.encode_sequence, probe)
    before = copy.deepcopy(wm.state_dict())
    assert {id(p) for p in loss.parameters()} == {id(p) for p in probe.parameters()}
    opt = torch.optim.Adam(probe.parameters(), lr=1e-2)
    td = linear_system_batch(batch=16, time=6, obs_dim=4)
    first = loss(td)["loss_probe"].item()
    for _ in range(150):
        out = loss(td)
        opt.zero_grad()
        out["loss_probe"].backward()
        assert all(p.grad is None for p in wm.parameters())
        opt.step()
    assert loss(td)["loss_probe"].item() < first / 2
    assert all(torch.equal(v, before[k]) for k, v in wm.state_dict().items())


def test_non_finite_loss_is_an_error():
    wm = _model()
    loss = SimDistPretrainLoss(wm, horizon=2, check_inputs=False)
    td = linear_system_batch(batch=2, time=5, obs_dim=4)
    td["value_target"][0, 0] = float("inf")
    with pytest.raises(FloatingPointError, match="loss_value"):
        loss(td)


def test_windows_cut_off_by_the_slice_are_not_trained_on():
    from simdist.objectives.simdist_pretrain import complete_windows
    is_init = torch.zeros(2, 6, dtype=torch.bool)
    is_init[1, 1] = True  # second slice: an episode starts at step 1
    ok = complete_windows(is_init, history=3)
    assert ok[0].tolist() == [False, False, True, True, True, True]
    assert ok[1].tolist() == [False, True, True, True, True, True]
    torch.manual_seed(0)
    wm = SimDistWorldModel.build(obs_dim=4, action_dim=2, size="tiny", history=3)
    z = torch.rand(2, 6, wm.latent_dim)
    _, _, mask = rollout_windows(wm, z, torch.zeros(2, 6, 2), is_init, horizon=2)
    assert mask[0, :2].sum() == 0 and mask[0, 2:].min() == 1  # mid-episode slice
    assert mask[1, 0].sum() == 0  # start 0 precedes the episode start (and would cross it)
    # an encoder that reads previous actions reads one step more: a_{t-3} for o_{t-2}
    wa = SimDistWorldModel.build(obs_dim=4, action_dim=2, size="tiny", history=3,
                                 previous_action=True)
    _, _, mask = rollout_windows(wa, z, torch.zeros(2, 6, 2), is_init, horizon=2)
    assert mask[0, :3].sum() == 0 and mask[0, 3:].min() == 1
    assert mask[1, 1:].min() == 1  # inside the episode every window is what the robot sees


def test_losses_and_the_probe_read_previous_actions_where_the_encoder_does():
    torch.manual_seed(0)
    wm = SimDistWorldModel.build(obs_dim=4, action_dim=2, size="tiny", previous_action=True)
    td = linear_system_batch(batch=4, time=8, obs_dim=4)
    pretrain, finetune = SimDistPretrainLoss(wm, horizon=2), DynamicsFinetuneLoss(wm, horizon=2)
    probe = ProbeLoss(wm.encode_sequence, StateDecoder(wm.latent_dim, 4, hidden=8),
                      with_actions=True)
    for loss in (pretrain, finetune, probe):
        assert all(torch.isfinite(v).all() for v in loss(td).values())
    # the latents depend on the previous actions, not only the dynamics' inputs
    is_init = td["is_init"][..., 0]
    shifted = td["action"].roll(1, 1)
    z = wm.encode_sequence(td["observation"], is_init, td["action"])
    assert not torch.allclose(z, wm.encode_sequence(td["observation"], is_init, shifted))
    with pytest.raises(Exception, match="action"):
        probe(td.exclude("action"))
    # a probe on a two-argument encoder is not handed the actions
    plain = SimDistWorldModel.build(obs_dim=4, action_dim=2, size="tiny")
    probe_plain = ProbeLoss(lambda obs, is_init: plain.encode_sequence(obs, is_init),
                            StateDecoder(plain.latent_dim, 4, hidden=8))
    assert torch.isfinite(probe_plain(td)["loss_probe"])


def test_a_dynamics_ensemble_averages_each_members_terms():
    # Each term is the mean over the dynamics members of the single-model term computed
    # with that member's dynamics; BC reads the shared encoder once.
    wm = _model()
    other = wm.fresh_dynamics()
    td = linear_system_batch(batch=2, time=6, obs_dim=4)
    out = SimDistPretrainLoss(wm, horizon=2, extra_dynamics=[other])(td)
    alone = SimDistPretrainLoss(wm, horizon=2)(td)
    second = SimDistPretrainLoss(wm.with_dynamics(other), horizon=2)(td)
    for term in ("loss_consistency", "loss_reward", "loss_value"):
        torch.testing.assert_close(out[term], (alone[term] + second[term]) / 2)
    torch.testing.assert_close(out["loss_bc"], alone["loss_bc"])
    # a member identical to the model's own dynamics changes nothing
    same = SimDistPretrainLoss(wm, horizon=2, extra_dynamics=[copy.deepcopy(wm.dynamics)])(td)
    for term in ("loss_consistency", "loss_reward", "loss_value", "loss_bc"):
        torch.testing.assert_close(same[term], alone[term])


def test_every_dynamics_member_and_the_shared_parts_get_gradients():
    wm = _model()
    extra = [wm.fresh_dynamics(), wm.fresh_dynamics()]
    # fresh initialisations: the members start apart
    assert not torch.equal(extra[0].net[0].weight, wm.dynamics.net[0].weight)
    loss = SimDistPretrainLoss(wm, horizon=2, extra_dynamics=extra)
    params = loss.trainable_parameters()
    assert {id(p) for p in params} == ({id(p) for p in wm.parameters()}
                                       | {id(p) for d in extra for p in d.parameters()})
    out = loss(linear_system_batch(batch=2, time=6, obs_dim=4))
    sum(v for k, v in out.items() if k.startswith("loss_")).backward()
    for module in (wm.encoder, wm.dynamics, *extra, wm.reward_head, wm.value_head):
        assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in module.parameters())


def test_prediction_skill_references_equal_hand_computation():
    from simdist.objectives.simdist_pretrain import (latent_prediction_error,
                                                     latent_prediction_skill)
    wm = _model()
    td = linear_system_batch(batch=3, time=7, obs_dim=4)
    td["is_init"][1, 3] = True  # an episode start inside a slice: windows stop there
    H = 2
    with torch.no_grad():
        skill = latent_prediction_skill(wm, td, horizon=H, seed=5)
        assert skill["model"] == pytest.approx(latent_prediction_error(wm, td, H))
        is_init = td["is_init"].squeeze(-1)
        z = wm.encode_sequence(td["observation"], is_init)
        _, targets, mask = rollout_windows(wm, z, td["action"], is_init, H)
        spread = z.reshape(-1, z.shape[-1]).var(0).sum()
        for i in range(H):  # "copy": z_t predicts z_{t+1+i}, over the unmasked windows
            err = sum(float(mask[b, s, i]) * float(((z[b, s] - z[b, s + 1 + i]) ** 2).sum())
                      for b in range(3) for s in range(7 - H))
            expected = err / float(mask[:, :, i].sum()) / float(spread)
            assert skill["copy"][i] == pytest.approx(expected, rel=1e-5)


def test_prediction_skill_shuffled_actions_matter_only_to_action_readers():
    from simdist.objectives.simdist_pretrain import latent_prediction_skill

    class Blind(torch.nn.Module):  # ignores its action: wrong actions change nothing
        def __init__(self, inner):
            super().__init__()
            self.inner, self.latent_dim, self.action_dim = inner, inner.latent_dim, inner.action_dim

        def forward(self, z, a):
            return self.inner(z, torch.zeros_like(a))

    wm = _model()
    td = linear_system_batch(batch=4, time=8, obs_dim=4)
    td["action"] = torch.randn_like(td["action"])
    with torch.no_grad():
        reads = latent_prediction_skill(wm, td, horizon=3)
        blind = latent_prediction_skill(wm.with_dynamics(Blind(wm.dynamics)), td, horizon=3)
    assert blind["shuffled"] == pytest.approx(blind["model"])
    assert reads["shuffled"] != pytest.approx(reads["model"])
    # a different seed permutes differently; the model and copy columns do not depend on it
    other = latent_prediction_skill(wm, td, horizon=3, seed=1)
    assert other["model"] == pytest.approx(reads["model"])
    assert other["copy"] == pytest.approx(reads["copy"])
