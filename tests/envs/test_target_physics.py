"""Each target-domain parameter measurably changes the physics, in the expected direction."""

import numpy as np
import pytest
import torch

from simdist.envs import TargetDomain, make_env


def _gait(t):
    # A fixed open-loop joint pattern: the same "actions" in every domain.
    return torch.tensor(0.8 * np.sin(0.3 * t + np.arange(12)), dtype=torch.float32)


def _zero(t):
    return torch.zeros(12)


def _run(target, policy, steps=100, task="quadruped-flat"):
    env = make_env(task, target=target, seed=0)
    td = env.reset()
    out, penetration = [], []
    for t in range(steps):
        td["action"] = policy(t)
        td = env.step(td)["next"]
        out.append(td.clone())
        d = env.sims[0].physics.data.ptr
        penetration.append(-min(0.0, float(d.contact.dist.min())) if d.ncon else 0.0)
    out = torch.stack(out)
    out.set("penetration", torch.tensor(penetration))
    return out, env


def _torso_height(rollout, env):
    return rollout["state"][50:, env.state_layout["qpos"]][:, 2].mean().item()


def test_lower_friction_makes_feet_slip_downhill():
    grippy, _ = _run(TargetDomain(slope_deg=12), _gait)
    slippery, _ = _run(TargetDomain(slope_deg=12, friction=0.3), _gait)
    assert slippery["forward_progress"][-1] < grippy["forward_progress"][-1] - 0.5


def test_slope_tilts_gravity_in_the_body_frame():
    flat, env = _run("sim", _zero, steps=30)
    slope, _ = _run(TargetDomain(slope_deg=12), _zero, steps=30)
    g = env.observation_layout["gravity"]
    assert abs(flat["observation"][-1, g][0]) < 0.02
    assert abs(slope["observation"][-1, g][0] - np.sin(np.deg2rad(12))) < 0.05


def test_softer_contact_sinks_deeper():
    hard, _ = _run("sim", _zero, steps=60)
    foam, _ = _run(TargetDomain(contact_softness=8.0), _zero, steps=60)
    assert foam["penetration"][20:].mean() > 4 * hard["penetration"][20:].mean()


@pytest.mark.parametrize("target", [TargetDomain(payload_kg=30.0),
                                    TargetDomain(motor_strength=0.45)])
def test_payload_and_weak_motors_lower_the_standing_torso(target):
    nominal, env = _run("sim", _zero)
    shifted, _ = _run(target, _zero)
    assert _torso_height(shifted, env) < _torso_height(nominal, env) - 0.01


def test_action_latency_delays_actuation_by_whole_steps():
    lagged, _ = _run(TargetDomain(action_latency=3), _gait, steps=8)
    idle, _ = _run("sim", _zero, steps=8)
    prompt, _ = _run("sim", _gait, steps=8)
    # The first three steps apply the zero-initialised queue, then the delayed actions.
    assert torch.equal(lagged["state"][:3], idle["state"][:3])
    assert not torch.allclose(lagged["state"][3:], prompt["state"][3:])


def test_dynamics_vector_reports_the_shift():
    rollout, _ = _run(TargetDomain(friction=0.3, payload_kg=5.0), _zero, steps=2)
    from simdist.envs import DynamicsParams
    fields = DynamicsParams.FIELDS
    assert rollout["dynamics"][0, fields.index("friction")].item() == pytest.approx(0.3)
    assert rollout["dynamics"][0, fields.index("payload_kg")].item() == pytest.approx(5.0)
