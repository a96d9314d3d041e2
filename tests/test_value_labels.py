"""experiments/value_labels.py: discounted returns and the steps before a tip-over."""

import numpy as np
import torch

from tests.in_process import benchmark_module


def test_returns_discount_to_the_episode_end_and_bootstrap_after_it():
    module = benchmark_module("value_labels")
    reward = torch.tensor([[1.0, 0.0, 2.0], [0.0, 0.0, 0.0]], dtype=torch.float64)
    out = module.discounted_returns(reward, torch.tensor([4.0, 8.0]), 0.5)
    # row 0: G2 = 2 + .5 * 4 = 4, G1 = 0 + .5 * 4 = 2, G0 = 1 + .5 * 2 = 2
    assert torch.allclose(out, torch.tensor([[2.0, 2.0, 4.0], [1.0, 2.0, 4.0]], dtype=torch.float64))


def test_steps_until_tip_count_down_per_episode_of_a_row():
    module = benchmark_module("value_labels")
    z = np.ones((2, 6))
    z[0, 3:] = -0.9  # row 0 tips at step 3 and stays down
    z[1, 1] = 0.2  # row 1: its first episode tips at step 1; a second starts at step 3
    init = np.zeros((2, 6), dtype=bool)
    init[:, 0] = init[1, 3] = True
    out = module.steps_until_tip(z, init)
    assert out[0].tolist() == [3, 2, 1, 0, -1, -1]
    assert out[1, :3].tolist() == [1, 0, -1] and np.isinf(out[1, 3:]).all()


def test_windows_before_tip_start_k_steps_before_and_fit_in_the_row():
    module = benchmark_module("value_labels")
    z = np.ones((3, 12))
    z[0, 6:] = -1.0  # tips at step 6: a window from step 2 (4 before) fits
    z[1, 3:] = -1.0  # tips at step 3: 4 before is step -1, no window
    z[2, 10:] = -1.0  # tips at step 10: starts at 6, but 6 + 8 steps leaves the row
    init = np.zeros((3, 12), dtype=bool)
    init[:, 0] = True
    until = module.steps_until_tip(z, init)
    rows, starts = module.windows_before_tip(until, 4, 8, first=1)
    assert rows.tolist() == [0] and starts.tolist() == [2]
    rows, _ = module.windows_before_tip(until, 4, 6, first=1)
    assert rows.tolist() == [0, 2]
    assert len(module.windows_before_tip(until, 4, 8, first=3)[0]) == 0


def test_upright_windows_come_from_episodes_that_never_tip():
    module = benchmark_module("value_labels")
    z = np.ones((3, 30))
    z[1, 15:] = -1.0  # tips at step 15: no window in an episode that tips
    init = np.zeros((3, 30), dtype=bool)
    init[:, 0] = True
    init[2, 12] = True  # a new episode at step 12: no window may reach past it
    until = module.steps_until_tip(z, init)
    at = module.upright_windows(until, init, horizon=10, every=10, first=0)
    assert at == [(0, 0), (0, 10), (0, 20), (2, 0)]
    assert module.upright_windows(until, init, horizon=10, every=10, first=5) == [
        (0, 5), (0, 15)]


def test_mean_of_heads_averages_and_fresh_copies_start_elsewhere():
    import torch
    from simdist.modules.heads import ScalarHead
    module = benchmark_module("value_labels")
    torch.manual_seed(0)
    head = ScalarHead(6, hidden=8)
    fresh = module._fresh_copy(head)
    x = torch.randn(5, 6)
    assert not torch.allclose(fresh(x), head(x))  # re-initialised, not a copy
    assert head.net[0].weight.data_ptr() != fresh.net[0].weight.data_ptr()
    torch.testing.assert_close(module.MeanOfHeads([head, fresh])(x), (head(x) + fresh(x)) / 2)
