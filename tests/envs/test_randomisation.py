import numpy as np
import pytest

from simdist.envs import DynamicsParams, DynamicsRandomisation, VisualRandomisation


def test_samples_lie_in_ranges_and_cover_them():
    dr = DynamicsRandomisation(friction=(0.5, 1.5), action_latency=(0, 2))
    rng = np.random.default_rng(0)
    draws = [dr.sample(rng) for _ in range(500)]
    friction = np.array([d.friction for d in draws])
    assert friction.min() >= 0.5 and friction.max() <= 1.5
    assert friction.min() < 0.55 and friction.max() > 1.45
    assert {d.action_latency for d in draws} == {0, 1, 2}
    assert all(all(dr.contains(d).values()) for d in draws)


def test_compose_multiplies_scales_and_adds_offsets():
    a = DynamicsParams(friction=0.5, motor_strength=2.0, payload_kg=1.0, action_latency=1)
    b = DynamicsParams(friction=0.5, motor_strength=0.25, payload_kg=2.0, action_latency=2)
    c = a.compose(b)
    assert (c.friction, c.motor_strength, c.payload_kg, c.action_latency) == (0.25, 0.5, 3.0, 3)
    assert c.as_array().dtype == np.float32 and len(c.as_array()) == len(DynamicsParams.FIELDS)


@pytest.mark.parametrize("kwargs, message", [
    (dict(friction=(1.2, 0.4)), "friction range is inverted"),
    (dict(mass=(0.0, 1.0)), "mass scales must be > 0"),
    (dict(damping=(-1.0, 1.0)), "damping must be >= 0"),
    (dict(motor_strength=(float("nan"), 1.0)), "motor_strength must be finite"),
    (dict(action_latency=(0.5, 1)), "integer steps"),
    (dict(contact_softness=(1.0,)), "must be a \\(low, high\\) pair"),
])
def test_invalid_dynamics_ranges_are_rejected(kwargs, message):
    with pytest.raises(ValueError, match=message):
        DynamicsRandomisation(**kwargs)


@pytest.mark.parametrize("kwargs, message", [
    (dict(friction=0.0), "friction must be finite and > 0"),
    (dict(action_latency=-1), "action_latency must be an integer >= 0"),
    (dict(payload_kg=float("inf")), "payload_kg must be finite"),
])
def test_invalid_dynamics_params_are_rejected(kwargs, message):
    with pytest.raises(ValueError, match=message):
        DynamicsParams(**kwargs)


def test_invalid_visual_settings_are_rejected():
    with pytest.raises(ValueError, match="valid splits"):
        VisualRandomisation(textures="test")
    with pytest.raises(ValueError, match="light_intensity range is inverted"):
        VisualRandomisation(light_intensity=(1.0, 0.5))
    with pytest.raises(ValueError, match="bank_size"):
        VisualRandomisation(bank_size=0)
