import pytest
import torch
from tensordict import TensorDict

from simdist.agents import SimDistAgent, SimDistConfig
from simdist.data import PrioritisedSlices, prioritised_update
from simdist.modules import SimDistWorldModel
from simdist.pipelines.resumable import train_resumable
from tests.synthetic import linear_system_batch


def _episodes(episodes=3, steps=10):
    step = torch.arange(steps).expand(episodes, steps)
    episode = torch.arange(episodes)[:, None].expand(episodes, steps)
    return TensorDict({"observation": (100 * episode + step).float()[..., None],
                       "is_init": (step == 0)[..., None]}, [episodes, steps])


def test_slices_are_contiguous_inside_one_episode_and_start_fresh():
    data = _episodes()
    slices = PrioritisedSlices(data, slice_len=4, batch_slices=500, alpha=1.0)
    assert len(slices) == 3 * (10 - 4 + 1)
    torch.manual_seed(0)
    batch = slices.sample()
    obs = batch["observation"][..., 0]
    assert batch.shape == (500, 4)
    assert torch.equal(obs[:, 1:] - obs[:, :-1], torch.ones(500, 3))  # consecutive steps
    assert torch.equal(torch.div(obs, 100, rounding_mode="floor"), batch["episode"].float())
    assert batch["is_init"][:, 0].all() and not batch["is_init"][:, 1:].any()
    start = batch["slice_start"][:, 0]
    assert torch.equal(obs[:, 0], (100 * (start // 7) + start % 7).float())
    assert set(start.tolist()) == set(range(len(slices)))  # every start can be drawn


def test_draws_follow_the_priorities_and_weights_are_the_importance_correction():
    slices = PrioritisedSlices(_episodes(), slice_len=4, batch_slices=20000, alpha=0.5,
                               beta=0.7, eps=1e-3)
    priority = torch.rand(len(slices)) * 4
    slices.update_priority(torch.arange(len(slices)), priority)
    expected = (priority + 1e-3) ** 0.5
    expected = expected / expected.sum()
    torch.testing.assert_close(slices.probabilities(), expected)
    torch.manual_seed(1)
    batch = slices.sample()
    start = batch["slice_start"][:, 0]
    freq = torch.bincount(start, minlength=len(slices)).float() / 20000
    assert (freq - expected).abs().max() < 0.01
    n = len(slices)
    weight = (n * expected[start]) ** -0.7  # hand-computed, then the batch's largest is 1
    torch.testing.assert_close(batch["priority_weight"][:, 0, 0], weight / weight.max())
    assert torch.equal(batch["priority_weight"][:, :1].expand(-1, 4, 1), batch["priority_weight"])


def test_alpha_zero_is_uniform_with_unit_weights():
    slices = PrioritisedSlices(_episodes(), slice_len=4, batch_slices=8, alpha=0.0, beta=1.0)
    slices.update_priority(torch.arange(len(slices)), torch.rand(len(slices)))
    torch.testing.assert_close(slices.probabilities(), torch.full((len(slices),), 1 / len(slices)))
    torch.testing.assert_close(slices.sample()["priority_weight"], torch.ones(8, 4, 1))


def test_measure_all_sets_every_start_and_state_round_trips():
    data = _episodes()
    slices = PrioritisedSlices(data, slice_len=4, batch_slices=2)
    seen = []

    def error(batch):
        seen.append(batch["slice_start"][:, 0])
        return batch["observation"][:, 0, 0] / 1000  # one value per slice
    slices.measure_all(error, chunk=5)
    assert torch.equal(torch.cat(seen), torch.arange(len(slices)))
    first_obs = torch.stack([data["observation"][s // 7, s % 7, 0] for s in range(len(slices))])
    torch.testing.assert_close(slices.priority, first_obs / 1000)
    other = PrioritisedSlices(data, slice_len=4, batch_slices=2)
    other.load_state_dict(slices.state_dict())
    assert torch.equal(other.priority, slices.priority)
    with pytest.raises(ValueError, match="other data"):
        PrioritisedSlices(_episodes(episodes=2), 4, 2).load_state_dict(slices.state_dict())


@pytest.mark.parametrize("kwargs, message", [
    ({"slice_len": 11}, "slice_len"), ({"batch_slices": 0}, "batch_slices"),
    ({"alpha": -1.0}, "alpha"), ({"beta": float("nan")}, "beta"), ({"eps": 0.0}, "eps"),
])
def test_bad_arguments_fail_clearly(kwargs, message):
    args = {"slice_len": 4, "batch_slices": 2, **kwargs}
    with pytest.raises(ValueError, match=message):
        PrioritisedSlices(_episodes(), **args)
    with pytest.raises(ValueError, match="episodes, steps"):
        PrioritisedSlices(_episodes().reshape(-1), 4, 2)


def test_bad_priorities_fail_clearly():
    slices = PrioritisedSlices(_episodes(), slice_len=4, batch_slices=2)
    with pytest.raises(ValueError, match="finite"):
        slices.update_priority(torch.tensor([0, 1]), torch.tensor([1.0, float("nan")]))
    with pytest.raises(ValueError, match="finite"):
        slices.update_priority(torch.tensor([0]), torch.tensor([-1.0]))
    with pytest.raises(ValueError, match="one priority per start"):
        slices.update_priority(torch.tensor([0, 1]), torch.tensor([1.0]))


def test_prioritised_update_writes_each_slice_error_to_its_start():
    slices = PrioritisedSlices(_episodes(), slice_len=4, batch_slices=3)
    batch = slices.slices(torch.tensor([2, 9, 15]))

    def step(b, slice_errors=False):
        assert slice_errors
        return {"loss_consistency": 1.0}, torch.tensor([0.5, 0.25, 0.125])
    assert prioritised_update(step, slices)(batch) == {"loss_consistency": 1.0}
    assert slices.priority[[2, 9, 15]].tolist() == [0.5, 0.25, 0.125]
    assert slices.priority.sum().item() == pytest.approx(0.875 + len(slices) - 3)


def test_large_alpha_stays_a_distribution_with_finite_weights():
    slices = PrioritisedSlices(_episodes(), slice_len=4, batch_slices=50, alpha=200.0, beta=1.0)
    slices.update_priority(torch.arange(len(slices)), torch.linspace(0.0, 5.0, len(slices)))
    p = slices.probabilities()
    assert torch.isfinite(p).all() and abs(p.sum().item() - 1) < 1e-5
    weight = slices.sample()["priority_weight"]
    assert torch.isfinite(weight).all() and (weight > 0).all()


def test_data_without_is_init_fails_clearly():
    data = TensorDict({"observation": torch.randn(2, 6, 1)}, [2, 6])
    with pytest.raises(KeyError, match="is_init"):
        PrioritisedSlices(data, slice_len=3, batch_slices=2).sample()


def _finetuning(tmp_path, stop_after=None):
    """Prioritised dynamics finetuning of a tiny agent, checkpointed every 2 updates;
    returns the priorities and every drawn start."""
    torch.manual_seed(0)
    agent = SimDistAgent(SimDistWorldModel.build(4, 2, size="tiny", history=2),
                         SimDistConfig(horizon=2))
    data = linear_system_batch(batch=4, time=12, obs_dim=4, seed=5)
    slices = PrioritisedSlices(data, slice_len=5, batch_slices=3, alpha=1.0, beta=0.5)
    slices.measure_all(agent.finetune_slice_errors)
    drawn = []

    def sample():
        batch = slices.sample()
        drawn.append(batch["slice_start"][:, 0].tolist())
        return batch
    state = {"wm": agent.world_model, "opt": agent.finetune_optim, "priorities": slices}
    update = prioritised_update(agent.finetune_update, slices)
    if stop_after is not None:  # a run killed after its checkpoint at stop_after updates
        train_resumable(update, sample, stop_after, state, tmp_path / "ft.ckpt", every=2,
                        progress=False, seed=1)
        return _finetuning_resumed(tmp_path, drawn)
    train_resumable(update, sample, 6, state, tmp_path / "ft.ckpt", every=2,
                    progress=False, seed=1)
    return slices.priority, drawn


def _finetuning_resumed(tmp_path, drawn_before):
    torch.manual_seed(123)  # whatever ran before must not matter
    agent = SimDistAgent(SimDistWorldModel.build(4, 2, size="tiny", history=2),
                         SimDistConfig(horizon=2))
    data = linear_system_batch(batch=4, time=12, obs_dim=4, seed=5)
    slices = PrioritisedSlices(data, slice_len=5, batch_slices=3, alpha=1.0, beta=0.5)
    drawn = list(drawn_before)

    def sample():
        batch = slices.sample()
        drawn.append(batch["slice_start"][:, 0].tolist())
        return batch
    state = {"wm": agent.world_model, "opt": agent.finetune_optim, "priorities": slices}
    train_resumable(prioritised_update(agent.finetune_update, slices), sample, 6, state,
                    tmp_path / "ft.ckpt", every=2, progress=False, seed=1)
    return slices.priority, drawn


def test_a_resumed_prioritised_finetuning_draws_what_the_uninterrupted_one_did(tmp_path):
    priority, drawn = _finetuning(tmp_path / "a")
    resumed_priority, resumed_drawn = _finetuning(tmp_path / "b", stop_after=4)
    assert len(drawn) == len(resumed_drawn) == 6
    assert drawn == resumed_drawn
    assert torch.equal(priority, resumed_priority)
    assert len({tuple(d) for d in drawn}) > 1  # the draws do differ from step to step
