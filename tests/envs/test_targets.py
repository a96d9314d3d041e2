import json
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
    with pytest.raises(ValueError, match=r"TargetDomain.friction must lie in \[0.01, 10.0\]"):
        TargetDomain(friction=-0.1)


@pytest.mark.parametrize("fields,error,message", [
    ({"friction": True}, TypeError, "TargetDomain.friction must be a number, got True"),
    ({"friction": "0.4"}, TypeError, "TargetDomain.friction must be a number, got '0.4'"),
    ({"name": 5}, TypeError, "TargetDomain.name must be a non-empty string"),
    ({"name": ""}, TypeError, "TargetDomain.name must be a non-empty string"),
    ({"friction": 1e308}, ValueError, "TargetDomain.friction must lie in"),
    ({"payload_kg": 1e30}, ValueError, "TargetDomain.payload_kg must lie in"),
    ({"action_latency": 100000}, ValueError, "TargetDomain.action_latency must lie in"),
    ({"action_latency": 1.5}, TypeError, "TargetDomain.action_latency must be an integer"),
    ({"action_latency": False}, TypeError, "TargetDomain.action_latency must be an integer"),
    ({"motor_strength": float("nan")}, ValueError, "TargetDomain.motor_strength must lie in"),
    ({"contact_softness": 0.0}, ValueError, "TargetDomain.contact_softness must lie in"),
])
def test_a_target_with_a_wrong_type_or_an_unphysical_value_is_refused_by_field(
        fields, error, message):
    """Exact types (no bools or strings for numbers) and physical bounds, checked when the
    target is built: before any environment, folder or stage (the recipes build it while
    parsing their flags)."""
    with pytest.raises(error, match=message):
        get_target(fields)
    with pytest.raises(error, match=message):
        get_target(json.dumps(fields))


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
    with pytest.raises(ValueError, match="TargetDomain.friction must lie in"):
        get_target({"friction": -1.0})
    with pytest.raises(TypeError, match="preset name, a dict"):
        get_target(0.3)
