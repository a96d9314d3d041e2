"""experiments/progress_by_command.py's count of rolled-over target episodes per command."""

import numpy as np
import torch
from tensordict import TensorDict

from tests.in_process import benchmark_module


def test_rows_holding_several_episodes_count_each_with_its_own_command():
    module = benchmark_module("progress_by_command")
    layout = module.observation_layout("quadruped-flat")
    command, up = layout["command"].start, layout["gravity"].start + 2
    obs = torch.zeros(2, 10, layout.size)
    obs[..., up] = 1.0
    obs[0, :, command] = 0.25  # row 0: one slow episode, upright throughout
    obs[1, :4, command] = 0.25  # row 1: a slow episode that ends on its back at step 3...
    obs[1, 4:, command] = 0.75  # ...and a fast one that the reset started at step 4
    next_obs = obs.roll(-1, 1)
    next_obs[1, 3, up] = -0.9  # the terminal reading: only the step's next observation
    nose = layout["gravity"].start  # ...reached over the tail: nose up one step before
    next_obs[1, 2, nose], next_obs[1, 3, nose] = -0.6, -0.4
    is_init = torch.zeros(2, 10, 1, dtype=torch.bool)
    is_init[:, 0] = is_init[1, 4] = True
    reward = torch.zeros(2, 10, 1)
    reward[0] = 0.5
    reward[1, 4:] = 0.9
    td = TensorDict({"observation": obs, "is_init": is_init, ("next", "observation"): next_obs,
                     ("next", "reward"): reward}, [2, 10])
    table = module.flips_by_command(td, "quadruped-flat").splitlines()
    # slow: 2 episodes, 14 steps, 1 on its back, over the tail 1 step after nose-up,
    # reward 5.0 / 14; fast: 1, 6 steps, none tipped, 0.9
    assert table[2:] == ["| 0.25 | 2 | 14 | 1 | 1 (1) | 1 | 0.36 |",
                         "| 0.75 | 1 | 6 | 0 | 0 (0) | - | 0.90 |"]


def test_tip_overs_tell_over_the_tail_from_sideways_and_time_the_nose_up():
    module = benchmark_module("progress_by_command")
    upright = np.tile([0.0, 0.0, 1.0], (6, 1))
    tail = upright.copy()
    tail[1:, 0] = -0.5  # nose up from step 1 on...
    tail[4] = [-0.9, 0.1, 0.4]  # ...tipped at step 4, over the tail
    side = upright.copy()
    side[2] = [-0.3, 0.9, 0.3]  # tipped at step 2 sideways (y beyond x)
    assert module.tip_overs([upright, tail, side]) == (2, 1, [3])
