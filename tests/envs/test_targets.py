import pytest

from simdist.envs import TARGETS, DynamicsRandomisation, TargetDomain, describe_ranges, get_target


@pytest.mark.parametrize("name", ["slippery_slope", "foam", "payload", "weak_motors", "laggy"])
def test_named_presets_lie_outside_the_training_ranges(name):
    target = get_target(name)
    training = DynamicsRandomisation()
    inside = training.contains(target.dynamics())
    shifted = [f for f, ok in inside.items() if not ok]
    assert shifted or target.payload_kg > 0, f"{name} lies inside every training range"
    if target.payload_kg:
        assert target.payload_kg > 0.15 * 107  # beyond +15% mass on the 107 kg quadruped


def test_unknown_target_lists_presets():
    with pytest.raises(ValueError, match="valid presets: .*slippery_slope"):
        get_target("moon")


def test_invalid_target_values():
    with pytest.raises(ValueError, match="slope_deg"):
        TargetDomain(slope_deg=45)
    with pytest.raises(ValueError, match="friction must be finite and > 0"):
        TargetDomain(friction=-0.1)


def test_describe_ranges_shows_every_preset():
    table = describe_ranges()
    for name in TARGETS:
        assert name in table
    assert "0.6 - 1.4" in table  # default training friction range


def test_a_dict_of_fields_is_a_target():
    from simdist.envs import make_env

    assert get_target({"friction": 0.3}) == TargetDomain(friction=0.3)
    env = make_env("cartpole-balance", target={"friction": 0.3, "name": "icy"}, seed=0)
    assert env.target == TargetDomain(name="icy", friction=0.3)
    with pytest.raises(ValueError, match="unknown TargetDomain field\\(s\\) \\['frcition'\\]"):
        get_target({"frcition": 0.3})
    with pytest.raises(ValueError, match="friction must be finite and > 0"):
        get_target({"friction": -1.0})
    with pytest.raises(TypeError, match="preset name, a dict"):
        get_target(0.3)
