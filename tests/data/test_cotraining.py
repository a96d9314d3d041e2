import pytest
import torch
from tensordict import TensorDict

from simdist.data import CoTrainingSlices


def _source(slices, length, value, extra=None):
    def sample():
        td = TensorDict({"observation": torch.full((slices, length, 3), value),
                         "is_init": torch.zeros(slices, length, 1, dtype=torch.bool),
                         "next": {"reward": torch.full((slices, length, 1), value)}},
                        [slices, length])
        if extra:
            td.set(extra, torch.zeros(slices, length))
        return td
    return sample


KEYS = ["observation", "is_init", ("next", "reward")]


def test_a_batch_is_the_target_slices_then_the_simulation_slices_flagged():
    mix = CoTrainingSlices(_source(3, 5, 1.0, extra="value_target"),
                           _source(2, 5, 2.0, extra="step"), KEYS)
    batch = mix()
    assert batch.shape == (5, 5)
    assert set(batch.keys(include_nested=True, leaves_only=True)) == {
        "observation", "is_init", ("next", "reward"), "from_simulation"}
    flag = batch["from_simulation"]
    assert flag.shape == (5, 5, 1) and flag.dtype == torch.bool
    assert flag[:, :, 0].tolist() == [[False] * 5] * 3 + [[True] * 5] * 2
    # the values come from their own source, row for row
    assert (batch["observation"][:3] == 1.0).all() and (batch["observation"][3:] == 2.0).all()
    assert (batch["next", "reward"][3:] == 2.0).all()


def test_each_call_draws_fresh_slices_from_both_sources():
    draws = []

    def counting(value):
        def sample():
            draws.append(value)
            return _source(1, 4, float(len(draws)))()
        return sample

    mix = CoTrainingSlices(counting("target"), counting("sim"), KEYS)
    first, second = mix(), mix()
    assert draws == ["target", "sim", "target", "sim"]
    assert not torch.equal(first["observation"], second["observation"])


def test_mismatched_sources_are_refused_with_the_reason():
    with pytest.raises(ValueError, match="keys must name"):
        CoTrainingSlices(_source(1, 4, 0.0), _source(1, 4, 0.0), [])
    with pytest.raises(KeyError, match="the simulation slices lack action "):
        CoTrainingSlices(_source(1, 4, 0.0, extra="action"), _source(1, 4, 0.0),
                         KEYS + ["action"])()
    with pytest.raises(ValueError, match="slice lengths differ: target 4, simulation 6"):
        CoTrainingSlices(_source(1, 4, 0.0), _source(1, 6, 0.0), KEYS)()
    flat = lambda: _source(1, 4, 0.0)().reshape(-1)  # noqa: E731
    with pytest.raises(ValueError, match=r"simulation source must return \[slices, slice_len\]"):
        CoTrainingSlices(_source(1, 4, 0.0), flat, KEYS)()

    def wide():
        td = _source(1, 4, 0.0)()
        td.set("observation", torch.zeros(1, 4, 5))
        return td
    with pytest.raises(ValueError, match="'observation' differs between target"):
        CoTrainingSlices(_source(1, 4, 0.0), wide, KEYS)()
