"""ReferencePolicy: blind zero / uniform actions, and what they score on cartpole-balance."""

import pytest
import torch
from tensordict import TensorDict

from simdist.pipelines import ReferencePolicy, evaluate_returns


def test_zero_and_uniform_actions_have_the_batch_shape_and_bounds():
    td = TensorDict({"state": torch.zeros(3, 4, 5)}, [3, 4])
    assert torch.equal(ReferencePolicy("zero", 2)(td.clone())["action"], torch.zeros(3, 4, 2))
    torch.manual_seed(0)
    actions = ReferencePolicy("uniform", 2, low=-0.5, high=1.5)(
        TensorDict({}, [5000]))["action"]
    assert actions.shape == (5000, 2)
    assert actions.min() >= -0.5 and actions.max() <= 1.5
    # uniform on [-0.5, 1.5]: mean 0.5, std 2 / sqrt(12)
    assert abs(actions.mean().item() - 0.5) < 0.03
    assert abs(actions.std().item() - 2 / 12 ** 0.5) < 0.03


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="unknown reference policy"):
        ReferencePolicy("constant", 1)
    with pytest.raises(ValueError, match="low < high"):
        ReferencePolicy("uniform", 1, low=1.0, high=1.0)
    with pytest.raises(ValueError, match="action_dim"):
        ReferencePolicy("zero", 0)


def test_doing_nothing_beats_random_pushes_on_cartpole_balance():
    """Why the TWIST recipe reports these references: the undamped pole swings back past
    upright under a zero action, and the smooth reward pays for it."""
    def returns(kind):
        return evaluate_returns("cartpole-balance", ReferencePolicy(kind, 1), None, 10_000,
                                episodes=4, steps=200, pixels=False, visual=None)
    zero, uniform = returns("zero"), returns("uniform")
    assert min(zero["returns"]) > max(uniform["returns"])
    assert returns("uniform")["returns"] == uniform["returns"]  # seeded by evaluate_returns
