"""The perturbation schedule's statistics match its configuration; state rides in the TensorDict."""


import numpy as np
import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictSequential
from torchrl.envs import InitTracker, ParallelEnv, TransformedEnv

from simdist.data import ActionPerturbation, PerturbationSchedule
from simdist.envs import make_env


def _runs(flags: np.ndarray, value: bool) -> list[int]:
    """Lengths of complete runs of ``value`` (first and last runs dropped: censored)."""
    lengths, count, seen_other = [], 0, False
    for f in flags:
        if f == value:
            count += 1
        else:
            if count and seen_other:
                lengths.append(count)
            count, seen_other = 0, True
    return lengths


def _simulate(schedule, envs=300, steps=3000, action_dim=3, seed=0):
    """Drives the module alone, carrying state like step_mdp does."""
    module = ActionPerturbation(action_dim, schedule, seed=seed)
    td = TensorDict({"is_init": torch.ones(envs, 1, dtype=torch.bool)}, [envs])
    noisy, stds, deltas = [], None, []
    for t in range(steps):
        td["action"] = torch.zeros(envs, action_dim)
        td = module(td)
        noisy.append(~td["expert_active"][:, 0])
        deltas.append(td["action"])
        stds = td["next", "perturbation", "std"] if stds is None else stds
        td = TensorDict({"is_init": torch.zeros(envs, 1, dtype=torch.bool),
                         "perturbation": td["next", "perturbation"]}, [envs])
    return torch.stack(noisy, 1).numpy(), stds, torch.stack(deltas, 1)


def test_burst_pause_lengths_std_range_and_never_fraction_match_the_schedule():
    schedule = PerturbationSchedule(std_range=(0.2, 0.6), burst_range=(2, 10),
                                    pause_range=(5, 30), never_noised_fraction=0.2,
                                    action_low=-100, action_high=100)
    noisy, stds, actions = _simulate(schedule)
    never = ~noisy.any(1)
    assert abs(never.mean() - 0.2) < 0.06  # 300 envs: binomial sd ~0.023
    bursts = [n for row in noisy[~never] for n in _runs(row, True)]
    pauses = [n for row in noisy[~never] for n in _runs(row, False)]
    assert min(bursts) >= 2 and max(bursts) <= 10 and abs(np.mean(bursts) - 6.0) < 0.3
    assert min(pauses) >= 5 and max(pauses) <= 30 and abs(np.mean(pauses) - 17.5) < 0.6
    assert stds.min() >= 0.2 and stds.max() <= 0.6 and abs(stds.mean().item() - 0.4) < 0.02
    # the noise applied during bursts has the per-joint std that was drawn
    env_index = np.flatnonzero(~never)[:50]
    for i in env_index[:10]:
        applied = actions[i][torch.from_numpy(noisy[i])]
        assert torch.allclose(applied.std(0), stds[i], rtol=0.35)
    assert (actions[torch.from_numpy(~noisy)] == 0).all()  # pauses: the expert's action


def test_noised_fraction_is_the_steady_state_from_the_first_step():
    # Reference defaults: E[burst] 25.5, E[pause] 262.5 -> 8.85% x (1 - 0.025) = 8.63%.
    schedule = PerturbationSchedule()
    assert abs(schedule.noised_fraction() - 25.5 / 288 * 0.975) < 1e-12
    noisy, _, _ = _simulate(schedule, envs=4000, steps=250, seed=0)
    per_step = noisy.mean(0)
    print(f"noised fraction {noisy.mean():.4f} (configured {schedule.noised_fraction():.4f}); "
          f"first 10 steps {per_step[:10].mean():.4f}, last 50 {per_step[-50:].mean():.4f}")
    # 1M draws, but bursts correlate steps: compare with a few-sd tolerance
    assert abs(noisy.mean() - schedule.noised_fraction()) < 0.006
    # no warm-up: the first steps are noised as often as any others
    assert abs(per_step[:10].mean() - schedule.noised_fraction()) < 0.012
    assert abs(per_step[-50:].mean() - schedule.noised_fraction()) < 0.012
    # episodes of 250 steps that are never noised: ~ never_noised + P(in one long pause)
    assert (~noisy.any(1)).mean() < 0.5


def test_dither_rides_on_pauses_of_perturbed_episodes_only():
    schedule = PerturbationSchedule(std_range=(2.0, 2.0), burst_range=(2, 10), pause_range=(5, 30),
                                    never_noised_fraction=0.3, dither_std=0.2,
                                    action_low=-100, action_high=100)
    noisy, _, actions = _simulate(schedule, envs=400, steps=400)
    never = torch.from_numpy(~noisy.any(1))
    pause = torch.from_numpy(~noisy) & ~never[:, None]
    # outside bursts: zero-mean noise of the configured std on every joint, still the expert's
    dithered = actions[pause]
    assert len(dithered) > 10_000
    assert torch.allclose(dithered.std(0), torch.full((3,), 0.2), rtol=0.03)
    assert dithered.mean(0).abs().max() < 0.01
    # bursts keep their own std (2.0), never-perturbed episodes stay exactly the expert's
    assert torch.allclose(actions[torch.from_numpy(noisy)].std(0), torch.full((3,), 2.0), rtol=0.05)
    assert (actions[never] == 0).all()
    # dither 0 is the reference schedule, draw for draw
    reference = PerturbationSchedule(std_range=(2.0, 2.0), burst_range=(2, 10), pause_range=(5, 30),
                                     never_noised_fraction=0.3, action_low=-100, action_high=100)
    ref_noisy, _, ref_actions = _simulate(reference, envs=400, steps=400)
    assert (ref_noisy == noisy).all()
    assert torch.equal(ref_actions[torch.from_numpy(noisy)], actions[torch.from_numpy(noisy)])
    assert (ref_actions[pause] == 0).all()


def test_perturbed_actions_stay_inside_per_joint_bounds():
    low, high = torch.tensor([-1.0, -1.0, -0.8]), torch.tensor([1.0, 1.1, 0.8])
    module = ActionPerturbation(3, PerturbationSchedule(std_range=(2.0, 2.5), burst_range=(5, 5),
                                                        pause_range=(1, 1)),
                                seed=0, action_low=low, action_high=high)
    td = TensorDict({"action": torch.zeros(2000, 3),
                     "is_init": torch.ones(2000, 1, dtype=torch.bool)}, [2000])
    out = module(td)
    applied = out["action"][~out["expert_active"][:, 0]]
    assert len(applied) > 500
    assert (applied >= low).all() and (applied <= high).all()
    # the bounds are reached on every joint: the clamp, not the noise, limits the action
    assert torch.allclose(applied.max(0).values, high) and torch.allclose(applied.min(0).values, low)
    with pytest.raises(ValueError, match="low < high"):
        ActionPerturbation(2, action_low=torch.ones(2), action_high=torch.zeros(2))


def test_new_episode_redraws_the_schedule():
    module = ActionPerturbation(2, seed=1)
    td = TensorDict({"action": torch.zeros(64, 2), "is_init": torch.ones(64, 1, dtype=torch.bool)}, [64])
    first = module(td)["next", "perturbation", "std"].clone()
    td2 = TensorDict({"action": torch.zeros(64, 2), "is_init": torch.ones(64, 1, dtype=torch.bool),
                      "perturbation": {"std": first}}, [64])
    assert not torch.equal(module(td2)["next", "perturbation", "std"], first)


def test_seeded_and_bounded():
    a = _simulate(PerturbationSchedule(), envs=8, steps=200, seed=3)
    b = _simulate(PerturbationSchedule(), envs=8, steps=200, seed=3)
    assert np.array_equal(a[0], b[0]) and torch.equal(a[2], b[2])
    assert a[2].abs().max() <= 1.0


def _perturbed_env(seed=0):
    env = TransformedEnv(make_env("cartpole-balance", seed=seed, max_episode_steps=30), InitTracker())
    module = ActionPerturbation(1, PerturbationSchedule(burst_range=(2, 4), pause_range=(2, 4)),
                                seed=seed)
    env.append_transform(module.make_primer())
    return env, module


def test_state_is_carried_through_env_rollouts_and_reset_per_episode():
    env, module = _perturbed_env()
    expert = lambda td: td.set("action", torch.zeros(1))  # noqa: E731
    policy = TensorDictSequential(expert, module)
    td = env.rollout(70, policy, break_when_any_done=False)
    assert td["expert_active"].dtype == torch.bool and td["expert_active"].shape == (70, 1)
    assert (~td["expert_active"]).any() and td["expert_active"].any()
    remaining = td["perturbation", "remaining"][:, 0]
    nxt = td["next", "perturbation", "remaining"][:, 0]
    # carried: the next step's input state is this step's output state (within episodes)
    same_episode = ~td["is_init"][1:, 0]
    assert torch.equal(remaining[1:][same_episode], nxt[:-1][same_episode])
    std = td["perturbation", "std"]
    starts = torch.nonzero(td["is_init"][:, 0]).flatten().tolist()
    assert starts[:3] == [0, 30, 60]  # episodes of 30 steps
    assert not torch.equal(td["next", "perturbation", "std"][0], td["next", "perturbation", "std"][30])
    # the recorded action is the applied (perturbed) one
    assert (td["action"][~td["expert_active"][:, 0]] != 0).any()


def test_works_with_parallel_workers():
    def make():
        return _perturbed_env()[0]
    env = ParallelEnv(2, make)
    try:
        module = ActionPerturbation(1, PerturbationSchedule(burst_range=(2, 4), pause_range=(2, 4)))
        expert = lambda td: td.set("action", torch.zeros(2, 1))  # noqa: E731
        td = env.rollout(12, TensorDictSequential(expert, module))
        assert td.shape == (2, 12) and (~td["expert_active"]).any()
    finally:
        env.close()


@pytest.mark.parametrize("kwargs, message", [
    (dict(std_range=(1.0, 0.5)), "std_range range is inverted"),
    (dict(pause_range=(2.5, 4)), "whole steps"),
    (dict(never_noised_fraction=1.5), "never_noised_fraction"),
    (dict(dither_std=-0.1), "dither_std"),
    (dict(dither_std=float("nan")), "dither_std"),
])
def test_bad_schedule_values(kwargs, message):
    with pytest.raises(ValueError, match=message):
        PerturbationSchedule(**kwargs)


def test_missing_init_tracker_is_a_clear_error():
    with pytest.raises(KeyError, match="InitTracker"):
        ActionPerturbation(1)(TensorDict({"action": torch.zeros(2, 1)}, [2]))


def test_missing_action_is_a_clear_error():
    with pytest.raises(KeyError, match="place it after the policy"):
        ActionPerturbation(1)(TensorDict({"is_init": torch.ones(2, 1, dtype=torch.bool)}, [2]))
