"""WorldModelEnsemble: each verb equals its members' outputs combined by hand; planning
with one member is planning with that member; mismatched members are refused."""

import pytest
import torch
from tensordict import TensorDict

from simdist.agents import SimDistAgent
from simdist.modules import LatentMPPIPlanner, PlannerConfig, SimDistWorldModel, WorldModelEnsemble

OBS, ACT = 10, 3


def _members(k=3):
    torch.manual_seed(0)
    return [SimDistWorldModel.build(OBS, ACT, size="tiny") for _ in range(k)]


def test_verbs_combine_members_by_hand():
    members = _members()
    ensemble = WorldModelEnsemble(members)
    L = members[0].latent_dim
    window = torch.randn(5, members[0].encoder.history, OBS)
    action = torch.randn(5, ACT)
    z = ensemble.encode(window)
    parts = [m.encode(window) for m in members]
    torch.testing.assert_close(z, torch.cat(parts, -1))
    assert ensemble.latent_dim == 3 * L == z.shape[-1]
    torch.testing.assert_close(ensemble.next(z, action),
                               torch.cat([m.next(p, action) for m, p in zip(members, parts)], -1))
    torch.testing.assert_close(ensemble.reward(z, action),
                               sum(m.reward(p, action) for m, p in zip(members, parts)) / 3)
    torch.testing.assert_close(ensemble.value(z),
                               sum(m.value(p) for m, p in zip(members, parts)) / 3)
    torch.testing.assert_close(ensemble.policy(z),
                               sum(m.policy(p) for m, p in zip(members, parts)) / 3)
    actions = torch.randn(5, 4, ACT)
    torch.testing.assert_close(ensemble.rollout(z, actions), torch.cat(
        [m.rollout(p, actions) for m, p in zip(members, parts)], -1))
    obs, is_init = torch.randn(2, 6, OBS), torch.zeros(2, 6, dtype=torch.bool)
    torch.testing.assert_close(ensemble.encode_sequence(obs, is_init), torch.cat(
        [m.encode_sequence(obs, is_init) for m in members], -1))


def test_pessimism_lowers_the_mean_by_the_members_spread():
    members = _members()
    ensemble = WorldModelEnsemble(members, pessimism=0.5)
    window, action = torch.randn(5, members[0].encoder.history, OBS), torch.randn(5, ACT)
    z = ensemble.encode(window)
    parts = [m.encode(window) for m in members]
    rewards = torch.stack([m.reward(p, action) for m, p in zip(members, parts)])
    values = torch.stack([m.value(p) for m, p in zip(members, parts)])
    # population std over three members, by hand
    for got, each in ((ensemble.reward(z, action), rewards), (ensemble.value(z), values)):
        mean = each.sum(0) / 3
        std = (((each - mean) ** 2).sum(0) / 3).sqrt()
        assert std.min() > 0
        torch.testing.assert_close(got, mean - 0.5 * std)
    # the prior's proposal is not a score: still the plain mean
    torch.testing.assert_close(ensemble.policy(z),
                               sum(m.policy(p) for m, p in zip(members, parts)) / 3)
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="pessimism"):
            WorldModelEnsemble(members, pessimism=bad)


def test_members_keep_their_own_parameters():
    members = _members(2)
    ensemble = WorldModelEnsemble(members)
    assert len(ensemble) == 2
    ours = {id(p) for p in ensemble.parameters()}
    assert ours == {id(p) for m in members for p in m.parameters()}


def test_one_member_plans_as_that_member():
    (member,) = _members(1)
    cfg = PlannerConfig(horizon=3, num_samples=32, num_elites=4, iterations=2,
                        policy_fraction=0.5, policy_noise=0.3)
    latent = member.encode(torch.randn(4, member.encoder.history, OBS)).detach()
    td = lambda: TensorDict({"latent": latent.clone()}, [4])  # noqa: E731
    alone = LatentMPPIPlanner.from_world_model(member, cfg, seed=1)(td())
    ensemble = LatentMPPIPlanner.from_world_model(WorldModelEnsemble([member]), cfg, seed=1)(td())
    torch.testing.assert_close(ensemble["action"], alone["action"])
    torch.testing.assert_close(ensemble["planner", "mean"], alone["planner", "mean"])


def test_agent_policy_plans_with_the_ensemble_from_observations():
    ensemble = WorldModelEnsemble(_members())
    agent = SimDistAgent(ensemble, planner_config=PlannerConfig(horizon=2, num_samples=8,
                                                                num_elites=2))
    policy = agent.policy(torch.full((ACT,), -0.5), torch.full((ACT,), 0.5))
    td = TensorDict({"observation": torch.randn(4, OBS),
                     "is_init": torch.ones(4, 1, dtype=torch.bool)}, [4])
    out = policy(td)
    assert out["action"].shape == (4, ACT) and out["action"].abs().max() <= 0.5
    assert out["planner", "latent"].shape == (4, ensemble.latent_dim)


def test_mismatched_or_missing_members_are_refused():
    with pytest.raises(ValueError, match="at least one member"):
        WorldModelEnsemble([])
    other = SimDistWorldModel.build(OBS, ACT, size="small")
    with pytest.raises(ValueError, match="member 1 has"):
        WorldModelEnsemble([_members(1)[0], other])
    ensemble = WorldModelEnsemble(_members(2))
    with pytest.raises(ValueError, match="latent"):
        ensemble.reward(torch.zeros(4, 5), torch.zeros(4, ACT))


def test_an_ensemble_of_models_that_read_previous_actions_encodes_with_them():
    torch.manual_seed(0)
    members = [SimDistWorldModel.build(6, 2, size="tiny", previous_action=True) for _ in range(2)]
    ensemble = WorldModelEnsemble(members)
    assert (ensemble.encoder.action_dim, ensemble.encoder.context) == (2, 3)
    obs, actions = torch.randn(3, 5, 6), torch.rand(3, 5, 2)
    is_init = torch.zeros(3, 5, dtype=torch.bool)
    z = ensemble.encode_sequence(obs, is_init, actions)
    torch.testing.assert_close(z, torch.cat([m.encode_sequence(obs, is_init, actions)
                                             for m in members], -1))
    with pytest.raises(ValueError, match="previous-action inputs"):
        WorldModelEnsemble([members[0], SimDistWorldModel.build(6, 2, size="tiny")])
