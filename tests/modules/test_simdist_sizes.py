"""The named SimDist world-model sizes build what their table says."""
import pytest
import torch

from simdist.modules import SIMDIST_SIZES, SimDistWorldModel


@pytest.mark.parametrize("size", sorted(SIMDIST_SIZES))
def test_each_size_builds_its_table_entry(size):
    spec = SIMDIST_SIZES[size]
    wm = SimDistWorldModel.build(obs_dim=10, action_dim=3, size=size)
    assert wm.encoder.history == spec["history"]
    assert wm.latent_dim == spec["latent_dim"]
    first_layer = next(m for m in wm.dynamics.modules() if isinstance(m, torch.nn.Linear))
    assert first_layer.out_features == spec["hidden"]
    z = wm.encode(torch.randn(2, spec["history"], 10))
    # SimNorm: each group of the latent is a probability vector.
    groups = z.reshape(2, spec["simnorm_groups"], -1).sum(-1)
    torch.testing.assert_close(groups, torch.ones_like(groups))


def test_wide_is_the_paper_width_on_the_small_history():
    wide = SimDistWorldModel.build(obs_dim=10, action_dim=3, size="wide")
    paper = SimDistWorldModel.build(obs_dim=10, action_dim=3, size="paper", history=4)
    small = SimDistWorldModel.build(obs_dim=10, action_dim=3, size="small")
    shapes = lambda m: {k: v.shape for k, v in m.state_dict().items()}  # noqa: E731
    assert shapes(wide) == shapes(paper)
    assert sum(p.numel() for p in wide.parameters()) > 2 * sum(p.numel() for p in small.parameters())
