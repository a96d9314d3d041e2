"""Held-out evaluation depends on the policy and the seed alone."""

import torch
from tensordict.nn import TensorDictModule

from simdist.pipelines import evaluate_returns


def _noisy_policy():
    """Draws its actions from torch's global generator, as a sampling Dreamer policy does."""
    return TensorDictModule(lambda state: torch.rand(state.shape[0], 1) * 2 - 1,
                            in_keys=["state"], out_keys=["action"])


def _evaluate(seed: int) -> dict:
    return evaluate_returns("cartpole-balance", _noisy_policy(), None, seed, episodes=2,
                            steps=15, pixels=False, visual=None)


def test_same_seed_same_returns_whatever_the_global_generator_state():
    torch.manual_seed(1)
    first = _evaluate(seed=7)
    torch.manual_seed(2)  # a different history before the evaluation
    torch.rand(1000)
    assert _evaluate(seed=7)["returns"] == first["returns"]
    assert _evaluate(seed=8)["returns"] != first["returns"]


def test_the_callers_random_stream_is_untouched():
    torch.manual_seed(3)
    expected = torch.rand(4)
    torch.manual_seed(3)
    _evaluate(seed=7)
    assert torch.equal(torch.rand(4), expected)
