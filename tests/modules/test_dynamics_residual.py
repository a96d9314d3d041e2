"""MLPDynamics' two residual forms on SimNorm latents: "additive" (every model before
2026-12-03) is not an identity at f = 0; "logit" starts exactly at "no change"."""
import pytest
import torch

from simdist.agents import SimDistAgent
from simdist.agents.describe import build_simdist_model, describe_simdist_model
from simdist.modules import MLPDynamics, SimDistWorldModel
from simdist.modules.encoders import simnorm


def zero_net(dyn: MLPDynamics) -> MLPDynamics:
    for p in dyn.net.parameters():
        torch.nn.init.zeros_(p)
    return dyn


def test_additive_residual_at_zero_change_blurs_the_latent():
    # norm(z + 0) = softmax(z) != z for a probability vector z: what "additive" did.
    torch.manual_seed(0)
    z = simnorm(3 * torch.randn(6, 16), 4)
    out = zero_net(MLPDynamics(16, 2, hidden=8, simnorm_groups=4))(z, torch.zeros(6, 2))
    torch.testing.assert_close(out, simnorm(z, 4))
    assert (out - z).abs().max() > 0.1


def test_logit_residual_starts_at_no_change_and_learns_a_change():
    torch.manual_seed(0)
    z = simnorm(3 * torch.randn(6, 16), 4)
    dyn = MLPDynamics(16, 2, hidden=8, simnorm_groups=4, residual="logit")
    torch.testing.assert_close(dyn(z, torch.randn(6, 2)), z, atol=1e-6, rtol=0)  # zero last layer
    # with a change f in the logits: norm(log z + f), each group still sums to one
    with torch.no_grad():
        [m for m in dyn.net.modules() if isinstance(m, torch.nn.Linear)][-1].bias.copy_(
            torch.linspace(-1, 1, 16))
    out = dyn(z, torch.randn(6, 2))
    expected = simnorm(torch.log(z) + torch.linspace(-1, 1, 16), 4)
    torch.testing.assert_close(out, expected)
    # gradients reach every layer although the last one starts at zero
    fresh = MLPDynamics(16, 2, hidden=8, simnorm_groups=4, residual="logit")
    (fresh(z, torch.randn(6, 2)) - simnorm(torch.randn(6, 16), 4)).pow(2).sum().backward()
    last = [m for m in fresh.net.modules() if isinstance(m, torch.nn.Linear)][-1]
    assert last.weight.grad.abs().sum() > 0


def test_logit_residual_survives_an_underflowed_group_entry():
    z = torch.zeros(1, 8)
    z[0, 0] = 1.0  # softmax can underflow to exact zeros in float32
    out = MLPDynamics(8, 1, hidden=4, simnorm_groups=1, residual="logit")(z, torch.zeros(1, 1))
    assert torch.isfinite(out).all()
    torch.testing.assert_close(out.sum(-1), torch.ones(1))


def test_without_simnorm_both_forms_are_the_plain_residual():
    z = torch.randn(3, 8)
    for residual in ("additive", "logit"):
        dyn = zero_net(MLPDynamics(8, 1, hidden=4, simnorm_groups=None, residual=residual))
        torch.testing.assert_close(dyn(z, torch.zeros(3, 1)), z)


def test_unknown_residual_is_refused():
    with pytest.raises(ValueError, match="unknown dynamics residual 'exp'"):
        MLPDynamics(8, 1, residual="exp")


def test_fresh_ensemble_dynamics_keep_the_logit_start():
    wm = SimDistWorldModel.build(10, 3, size="tiny", dynamics_residual="logit")
    z = simnorm(torch.randn(4, wm.latent_dim), 4)
    fresh = wm.fresh_dynamics()
    assert fresh is not wm.dynamics and fresh.residual == "logit"
    torch.testing.assert_close(fresh(z, torch.randn(4, 3)), z, atol=1e-6, rtol=0)


def test_the_residual_is_described_and_old_descriptions_read_as_additive(tmp_path):
    logit = SimDistWorldModel.build(10, 3, size="tiny", dynamics_residual="logit")
    desc = describe_simdist_model(logit)
    assert desc["dynamics_residual"] == "logit"
    assert build_simdist_model(desc).dynamics.residual == "logit"
    old = describe_simdist_model(SimDistWorldModel.build(10, 3, size="tiny"))
    assert "dynamics_residual" not in old  # files from before the option stay as they were
    assert build_simdist_model(old).dynamics.residual == "additive"
    path = SimDistAgent(logit).save(tmp_path / "a.pt")
    assert SimDistAgent.load(path).world_model.dynamics.residual == "logit"
