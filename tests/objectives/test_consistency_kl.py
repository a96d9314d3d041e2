"""The finetuning's KL consistency term on SimNorm groups (DynamicsFinetuneLoss(consistency="kl"))."""

import copy

import pytest
import torch
from torch.distributions import Categorical, kl_divergence

from simdist.modules import SimDistWorldModel
from simdist.modules.encoders import simnorm
from simdist.objectives import DynamicsFinetuneLoss
from simdist.objectives.simdist_pretrain import consistency_error
from tests.synthetic import ScaleDynamics, linear_system_batch


def _model(seed=0, **overrides):
    torch.manual_seed(seed)
    return SimDistWorldModel.build(obs_dim=4, action_dim=2, size="tiny", **overrides)


def test_kl_equals_torch_distributions_summed_over_groups():
    torch.manual_seed(0)
    predicted, target = simnorm(torch.randn(5, 3, 12), 3), simnorm(3 * torch.randn(5, 3, 12), 3)
    reference = kl_divergence(Categorical(probs=target.unflatten(-1, (3, 4))),
                              Categorical(probs=predicted.unflatten(-1, (3, 4)))).sum(-1)
    torch.testing.assert_close(consistency_error(predicted, target, 3, "kl"), reference)
    torch.testing.assert_close(consistency_error(predicted, target, 3, "squared"),
                               (predicted - target).pow(2).sum(-1))
    assert (consistency_error(target, target, 3, "kl").abs() < 1e-6).all()


def test_kl_gradient_on_the_logits_is_prediction_minus_target():
    logits = torch.tensor([[6.0, 0.0, 0.0, 0.0, 1.0, 2.0, 0.0, -1.0]], requires_grad=True)
    target = simnorm(torch.tensor([[0.0, 6.0, 0.0, 0.0, 0.0, 0.0, 3.0, 0.0]]), 2)
    consistency_error(simnorm(logits, 2), target, 2, "kl").sum().backward()
    torch.testing.assert_close(logits.grad, (simnorm(logits, 2) - target).detach())


def test_a_confidently_wrong_group_keeps_its_gradient_under_kl_only():
    target = torch.tensor([[0.0, 1.0]])
    grads = {}
    for kind in ("squared", "kl"):
        logits = torch.tensor([[8.0, 0.0]], requires_grad=True)  # 0.9997 on the wrong entry
        consistency_error(simnorm(logits, 1), target, 1, kind).sum().backward()
        grads[kind] = logits.grad.abs().max().item()
    # squared: 2 (p - q) through the softmax Jacobian, ~4 p (1 - p); KL: |p - q| ~ 1
    assert grads["kl"] == pytest.approx(1.0, abs=1e-3)
    assert grads["squared"] == pytest.approx(4 * torch.sigmoid(torch.tensor(-8.0)).item(),
                                             rel=1e-2)
    assert grads["kl"] > 200 * grads["squared"]


def test_kl_finetuning_changes_only_the_dynamics_and_fits():
    wm = _model()
    loss = DynamicsFinetuneLoss(wm, horizon=3, consistency="kl")
    assert loss.trainable_parameters() == list(wm.dynamics.parameters())
    frozen = {name: copy.deepcopy(part.state_dict()) for name, part in wm.parts().items()
              if name != "dynamics"}
    opt = torch.optim.Adam(wm.parameters(), lr=1e-2)  # deliberately every parameter
    td = linear_system_batch(batch=8, time=8, obs_dim=4, seed=3)
    first = loss(td)["loss_consistency"].item()
    for _ in range(100):
        opt.zero_grad()
        loss(td)["loss_consistency"].backward()
        assert all(p.grad is None for name, part in wm.parts().items() if name != "dynamics"
                   for p in part.parameters())
        opt.step()
    for name, state in frozen.items():
        for k, v in getattr(wm, name).state_dict().items():
            assert torch.equal(v, state[k]), (name, k)
    assert loss(td)["loss_consistency"].item() < first / 2


def test_kl_loss_equals_hand_computation_and_ranks_slices():
    wm = _model()
    td = linear_system_batch(batch=2, time=5, obs_dim=4)
    out = DynamicsFinetuneLoss(wm, horizon=2, consistency="kl")(td)
    groups = wm.encoder.simnorm_groups
    z = wm.encode_sequence(td["observation"], td["is_init"].squeeze(-1))
    terms = []
    for t in range(3):
        zi = z[:, t]
        for i in range(2):
            zi = wm.next(zi, td["action"][:, t + i])
            target = z[:, t + i + 1].unflatten(-1, (groups, -1))
            terms.append((target * (target.log() - zi.unflatten(-1, (groups, -1)).log()))
                         .sum((-2, -1)))
    terms = torch.stack(terms)                                              # [S * H, B]
    torch.testing.assert_close(out["loss_consistency"], terms.mean())
    torch.testing.assert_close(out["slice_error"], terms.mean(0))


@pytest.mark.parametrize("kwargs, match", [
    (dict(consistency="cosine"), "unknown consistency 'cosine'"),
    (dict(consistency="kl", simnorm_groups=None), "needs a SimNorm latent")])
def test_bad_consistency_is_refused(kwargs, match):
    consistency = kwargs.pop("consistency")
    with pytest.raises(ValueError, match=match):
        DynamicsFinetuneLoss(_model(**kwargs), consistency=consistency)
    with pytest.raises(ValueError, match="unknown consistency"):
        consistency_error(torch.zeros(1, 4), torch.zeros(1, 4), 1, "cosine")


def test_a_custom_dynamics_without_simnorm_attributes_finetunes_with_either_term():
    wm = _model(dynamics=ScaleDynamics(action_dim=2))  # no simnorm_groups of its own
    td = linear_system_batch(batch=2, time=6, obs_dim=4)
    for kind in ("squared", "kl"):  # the groups are the encoder's
        DynamicsFinetuneLoss(wm, horizon=2, consistency=kind)(td)["loss_consistency"].backward()
        assert wm.dynamics.scale.grad is not None
