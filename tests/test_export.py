"""torch.export round trips: each exported step equals the TorchRL policy it comes from."""

import dataclasses

import pytest
import torch
from tensordict import TensorDict

from simdist.agents import DreamerAgent, DreamerConfig, SimDistAgent, TwistStudent
from simdist.export import (RecurrentPolicyStep, SimDistPlanStep, export_dreamer_policy,
                            export_simdist_policy, export_twist_policy)
from simdist.modules import DreamerWorldModel, PlannerConfig, SimDistWorldModel

# policy proposals on (40 * 0.1 = 4 candidates), warm start on, two iterations
PLANNER = PlannerConfig(horizon=3, num_samples=40, num_elites=4, iterations=2,
                        policy_fraction=0.1)


@pytest.mark.parametrize("previous_action", [False, True])
def test_exported_simdist_step_plans_what_the_torchrl_policy_plans(tmp_path, previous_action):
    torch.manual_seed(0)
    agent = SimDistAgent(SimDistWorldModel.build(10, 3, size="tiny",
                                                 previous_action=previous_action))
    low, high = -torch.full((3,), 0.8), torch.full((3,), 0.6)
    policy = agent.policy(low, high, PLANNER, seed=7)
    program = export_simdist_policy(policy)
    torch.export.save(program, tmp_path / "simdist.pt2")
    run = torch.export.load(tmp_path / "simdist.pt2").module()
    step = SimDistPlanStep(policy)
    assert step.uses_policy and step.num_random == 36
    generator = torch.Generator().manual_seed(7)  # the planner's seed: the planner's draws
    B = 3
    history, _, _, mean, *_ = step.example_inputs(B)
    history_td = None
    for t in range(4):
        obs = torch.randn(B, 10)
        is_init = torch.full((B, 1), t == 0)
        is_init[1] = t in (0, 2)  # env 1 starts a new episode at step 2
        td = TensorDict({"observation": obs, "is_init": is_init}, [B])
        if history_td is not None:
            td.set(("simdist", "history"), history_td)
        if previous_action:
            td.set(("simdist", "previous_action"),
                   torch.zeros(B, 3) if t == 0 else out["next", "simdist", "previous_action"])
        out = policy(td)
        history_td = out["next", "simdist", "history"]
        action, history, mean = run(history, obs, is_init, mean,
                                    *step.draw_noise(B, generator))
        assert torch.equal(action, out["action"]), t
        assert torch.equal(history, history_td) and torch.equal(mean, out["planner", "mean"])
        assert (action >= low).all() and (action <= high).all()


def test_exported_simdist_step_takes_any_batch_size():
    agent = SimDistAgent(SimDistWorldModel.build(10, 3, size="tiny"))
    policy = agent.policy(config=PLANNER)
    program, step = export_simdist_policy(policy).module(), SimDistPlanStep(policy)
    for B in (1, 5):
        inputs = step.example_inputs(B, torch.Generator().manual_seed(B))
        inputs[1].normal_()
        for a, b in zip(program(*inputs), step(*inputs)):
            assert torch.equal(a, b)


def test_exporting_a_latency_compensating_policy_is_refused():
    # its step would plan from the latent now instead of after the actions in flight
    agent = SimDistAgent(SimDistWorldModel.build(10, 3, size="tiny"))
    policy = agent.policy(config=dataclasses.replace(PLANNER, latency_compensation=2))
    with pytest.raises(ValueError, match="latency"):
        SimDistPlanStep(policy)
    with pytest.raises(ValueError, match="latency"):
        export_simdist_policy(policy)


def _recurrent_round_trip(policy, program, obs_key, observations, rssm):
    belief = stoch = prev_action = td_state = None
    for t, obs in enumerate(observations):
        B = obs.shape[0]
        is_init = torch.full((B, 1), t == 0)
        td = TensorDict({obs_key: obs, "is_init": is_init}, [B])
        if td_state is not None:
            td.set("agent", td_state)
        torch.manual_seed(100 + t)
        out = policy(td)
        td_state = out["next", "agent"]
        torch.manual_seed(100 + t)
        noise = torch.rand(B, rssm.stoch, rssm.classes)  # the policy's rand_like draw
        if belief is None:
            belief, stoch = torch.zeros(B, rssm.deter_dim), torch.zeros(B, rssm.stoch_dim)
            prev_action = torch.zeros(B, rssm.action_dim)
        action, belief, stoch = program(obs, belief, stoch, prev_action, is_init, noise)
        prev_action = action
        assert torch.equal(action, out["action"]), t
        assert torch.equal(belief, td_state["belief"]) and torch.equal(stoch, td_state["stoch"])


def test_exported_twist_step_acts_as_the_student_policy(tmp_path):
    torch.manual_seed(0)
    teacher = DreamerAgent.for_state(5, 2, DreamerConfig(size="tiny"))
    student = DreamerWorldModel.student(2, size="tiny", norm="layer", input_norm="image")
    twist = TwistStudent(teacher, student)
    program = export_twist_policy(twist)
    torch.export.save(program, tmp_path / "twist.pt2")
    frames = [torch.randint(0, 255, (3, 64, 64, 3), dtype=torch.uint8) for _ in range(3)]
    _recurrent_round_trip(twist.policy(), torch.export.load(tmp_path / "twist.pt2").module(),
                          "pixels", frames, student.rssm)


def test_exported_dreamer_step_acts_as_the_teacher_policy():
    torch.manual_seed(0)
    agent = DreamerAgent.for_state(5, 2, DreamerConfig(size="tiny"))
    states = [torch.randn(2, 5) for _ in range(3)]
    _recurrent_round_trip(agent.policy(explore=False), export_dreamer_policy(agent).module(),
                          "state", states, agent.world_model.rssm)
    step = RecurrentPolicyStep(agent.world_model, agent.actor)
    assert step(*step.example_inputs(torch.zeros(1, 5)))[0].shape == (1, 2)
