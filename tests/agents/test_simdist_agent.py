"""SimDist agent: a planning policy with its history in the TensorDict; finetuning scope."""

import copy

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs import InitTracker, TransformedEnv

from simdist.agents import SimDistAgent, SimDistConfig
from simdist.agents.simdist import SimDistPolicy
from simdist.envs import make_env
from simdist.modules import SimDistWorldModel
from simdist.modules.planner import PlannerConfig
from tests.synthetic import linear_system_batch


def _agent(obs_dim=89, action_dim=12, lr=2e-4, mixed_precision="none"):
    torch.manual_seed(0)
    return SimDistAgent(SimDistWorldModel.build(obs_dim, action_dim, size="tiny", history=3),
                        SimDistConfig(horizon=3, lr=lr, mixed_precision=mixed_precision))


def _rollout(agent, iterations=2):
    """8 steps of 2 quadrupeds whose episodes restart after 5 steps, planned by ``agent``."""
    env = TransformedEnv(make_env("quadruped-flat", seed=0, max_episode_steps=5, num_envs=2),
                         InitTracker())
    env.append_transform(agent.make_primer())
    spec = env.action_spec
    policy = agent.policy(spec.space.low[0], spec.space.high[0],
                          PlannerConfig(horizon=3, num_samples=16, num_elites=4,
                                        iterations=iterations))
    return env.rollout(8, policy, break_when_any_done=False), spec, policy


def test_planning_policy_runs_in_env_with_history_reset_per_episode():
    td, spec, _ = _rollout(_agent())
    low, high = spec.space.low[0], spec.space.high[0]
    assert ((td["action"] >= low) & (td["action"] <= high)).all()
    history = td["next", "simdist", "history"]                 # [2, 8, k, obs]
    obs = td["observation"]
    # newest entry is the current observation; at an episode start the window repeats it
    torch.testing.assert_close(history[..., -1, :], obs)
    starts = td["is_init"][..., 0]
    assert starts[:, 5].all()
    torch.testing.assert_close(history[:, 5], obs[:, 5, None].expand_as(history[:, 5]))
    torch.testing.assert_close(history[:, 6, :-1], history[:, 5, 1:])  # shifts by one


@pytest.mark.parametrize("mixed_precision", ["none", "bfloat16"])
def test_finetune_update_moves_only_dynamics_and_whole_ablation_moves_encoder(mixed_precision):
    agent = _agent(obs_dim=4, action_dim=2, mixed_precision=mixed_precision)
    batch = linear_system_batch(batch=8, time=8, obs_dim=4)
    before = copy.deepcopy(agent.world_model.state_dict())
    for _ in range(3):
        agent.finetune_update(batch.clone())
    changed = {k.split(".")[0] for k, v in agent.world_model.state_dict().items()
               if not torch.equal(v, before[k])}
    assert changed == {"dynamics"}
    for _ in range(3):
        agent.finetune_whole_update(batch.clone())
    changed = {k.split(".")[0] for k, v in agent.world_model.state_dict().items()
               if not torch.equal(v, before[k])}
    assert {"dynamics", "encoder"} <= changed


def test_finetune_update_reports_the_slice_errors_it_trained_on():
    agent = _agent(obs_dim=4, action_dim=2)
    batch = linear_system_batch(batch=6, time=8, obs_dim=4)
    before = agent.finetune_slice_errors(batch.clone())
    assert before.shape == (6,) and (before > 0).all()
    plain = copy.deepcopy(agent)
    metrics, errors = agent.finetune_update(batch.clone(), slice_errors=True)
    torch.testing.assert_close(errors, before)  # measured before the step it drives
    assert metrics == plain.finetune_update(batch.clone())  # same step, same metrics
    assert "slice_error" not in metrics
    after = agent.finetune_slice_errors(batch.clone())
    assert not torch.equal(after, before)
    _, whole_errors = agent.finetune_whole_update(batch.clone(), slice_errors=True)
    torch.testing.assert_close(whole_errors, after)
    # a dynamics ensemble reports its members' mean error per slice
    torch.manual_seed(0)
    ensemble = SimDistAgent(SimDistWorldModel.build(4, 2, size="tiny"),
                            SimDistConfig(horizon=2, dynamics_members=3))
    members = torch.stack([loss(batch.clone())["slice_error"].detach()
                           for loss in ensemble.finetune_losses])
    assert not torch.equal(members[0], members[1])
    torch.testing.assert_close(ensemble.finetune_slice_errors(batch.clone()), members.mean(0))
    _, errors = ensemble.finetune_update(batch.clone(), slice_errors=True)
    torch.testing.assert_close(errors, members.mean(0))


def test_pretraining_updates_reduce_the_loss():
    agent = _agent(obs_dim=4, action_dim=2, lr=3e-3)
    batch = linear_system_batch(batch=16, time=10, obs_dim=4)
    first = agent.pretrain_update(batch.clone())
    for _ in range(100):
        last = agent.pretrain_update(batch.clone())
    assert last["loss_reward"] < first["loss_reward"] / 2


def test_bfloat16_updates_keep_float32_weights_and_latents_and_match_float32_losses():
    batch = linear_system_batch(batch=16, time=10, obs_dim=4)
    full, mixed = _agent(4, 2), _agent(4, 2, mixed_precision="bfloat16")
    mixed.world_model.load_state_dict(full.world_model.state_dict())
    with mixed._autocast():
        latents = mixed.world_model.encode_sequence(batch["observation"], batch["is_init"][..., 0])
        rolled = mixed.world_model.rollout(latents[:, 0], batch["action"][:, :3])
    assert latents.dtype == rolled.dtype == torch.float32  # SimNorm runs in float32
    first_full, first_mixed = full.pretrain_update(batch.clone()), mixed.pretrain_update(batch.clone())
    for key in ("loss_consistency", "loss_reward", "loss_value", "loss_bc"):
        # bfloat16 keeps ~3 significant digits: the same loss to within a few percent
        assert first_mixed[key] == pytest.approx(first_full[key], rel=0.05, abs=1e-4), key
    assert all(p.dtype == torch.float32 for p in mixed.world_model.parameters())
    assert all(s.dtype == torch.float32 for state in mixed.pretrain_optim.state.values()
               for s in state.values() if s.is_floating_point() and s.dim() > 0)


def test_bfloat16_pretraining_reduces_the_loss_and_unknown_precisions_are_refused():
    agent = _agent(obs_dim=4, action_dim=2, lr=3e-3, mixed_precision="bfloat16")
    batch = linear_system_batch(batch=16, time=10, obs_dim=4)
    first = agent.pretrain_update(batch.clone())
    for _ in range(100):
        last = agent.pretrain_update(batch.clone())
    assert last["loss_reward"] < first["loss_reward"] / 2
    with pytest.raises(ValueError, match="unknown mixed_precision 'float8'"):
        _agent(4, 2, mixed_precision="float8")


def test_latency_compensation_plans_from_the_latent_rolled_through_actions_in_flight():
    agent = _agent()
    planner = PlannerConfig(horizon=3, num_samples=16, num_elites=4, iterations=1,
                            latency_compensation=2)
    env = TransformedEnv(make_env("quadruped-flat", seed=0, max_episode_steps=5, num_envs=2),
                         InitTracker())
    env.append_transform(agent.make_primer(latency_compensation=2))
    spec = env.action_spec
    policy = agent.policy(spec.space.low[0], spec.space.high[0], planner)
    seen = []  # the latent each planning call starts from
    policy.planner.register_forward_pre_hook(lambda m, args: seen.append(args[0]["latent"]))
    td = env.rollout(8, policy, break_when_any_done=False)
    sent = td["next", "simdist", "pending_actions"]            # [2, 8, 2, A]
    # the newest pending action is the one just chosen; the line shifts by one per step
    torch.testing.assert_close(sent[:, :, -1], td["action"])
    torch.testing.assert_close(sent[:, 1:5, 0], td["action"][:, :4])
    # a new episode (step 5) starts with nothing in flight: zeros, then its first action
    assert td["is_init"][:, 5].all()
    assert (sent[:, 5, 0] == 0).all()
    # the plan at step 6 starts two model steps ahead of z_6, through the actions in
    # flight then: (0, a_5), the episode having started at step 5
    with torch.no_grad():
        z6 = td["planner", "latent"][:, 6]
        expected = agent.world_model.rollout(
            z6, torch.stack([torch.zeros_like(td["action"][:, 5]), td["action"][:, 5]], 1))
    torch.testing.assert_close(seen[6], expected[:, -1])
    # without the primer key the policy refuses instead of planning from zeros
    bare = TransformedEnv(make_env("quadruped-flat", seed=0, max_episode_steps=5, num_envs=2),
                          InitTracker())
    bare.append_transform(agent.make_primer(latency_compensation=0))
    with pytest.raises(KeyError, match="make_primer"):
        bare.rollout(2, policy)
    with pytest.raises(ValueError, match="latency_compensation"):
        PlannerConfig(latency_compensation=-1)


def test_a_dynamics_ensemble_trains_saves_and_plans_as_shared_members(tmp_path):
    from simdist.modules import WorldModelEnsemble
    torch.manual_seed(0)
    wm = SimDistWorldModel.build(4, 2, size="tiny")
    agent = SimDistAgent(wm, SimDistConfig(horizon=2, dynamics_members=3))
    members = agent.members()
    assert len(members) == 3 and members[0] is wm
    assert all(m.encoder is wm.encoder and m.value_head is wm.value_head for m in members)
    assert len({id(m.dynamics) for m in members}) == 3
    before = [copy.deepcopy(m.dynamics.state_dict()) for m in members]
    agent.pretrain_update(linear_system_batch(batch=4, time=6, obs_dim=4))
    for m, old in zip(members, before):  # the optimiser holds every member's dynamics
        assert any(not torch.equal(v, old[k]) for k, v in m.dynamics.state_dict().items())
    path = agent.save(tmp_path / "agent.pt")
    loaded = SimDistAgent.load(path)
    for m, n in zip(members, loaded.members()):
        for k, v in m.state_dict().items():
            assert torch.equal(v, n.state_dict()[k]), k
    z = WorldModelEnsemble(loaded.members()).encode(torch.randn(5, wm.encoder.history, 4))
    assert z.shape == (5, 3 * wm.latent_dim)
    assert isinstance(loaded.policy().world_model, WorldModelEnsemble)  # plans with all three
    # SimDist finetuning moves every member's dynamics and nothing they share
    shared = copy.deepcopy(loaded.world_model.encoder.state_dict())
    before = [copy.deepcopy(m.dynamics.state_dict()) for m in loaded.members()]
    loaded.finetune_update(linear_system_batch(batch=4, time=6, obs_dim=4))
    for m, old in zip(loaded.members(), before):
        assert any(not torch.equal(v, old[k]) for k, v in m.dynamics.state_dict().items())
    assert all(torch.equal(v, shared[k]) for k, v in loaded.world_model.encoder.state_dict().items())
    with pytest.raises(ValueError, match="dynamics_members must be >= 1"):
        SimDistAgent(wm, SimDistConfig(dynamics_members=0))


def test_with_dynamics_refuses_a_dynamics_of_another_latent_size():
    from simdist.modules.simdist_model import MLPDynamics
    wm = SimDistWorldModel.build(4, 2, size="tiny")
    with pytest.raises(ValueError):
        wm.with_dynamics(MLPDynamics(latent_dim=8, action_dim=2, hidden=16, simnorm_groups=4))


def test_a_policy_whose_encoder_reads_previous_actions_encodes_what_training_encodes(tmp_path):
    torch.manual_seed(0)
    wm = SimDistWorldModel.build(89, 12, size="tiny", history=3, previous_action=True)
    agent = SimDistAgent(wm, SimDistConfig(horizon=3))
    td, _, policy = _rollout(agent, iterations=1)
    history = td["next", "simdist", "history"]             # [2, 8, 3, 89 + 12]
    assert history.shape[-1] == 101
    # newest entry: (o_t, a_{t-1}); zeros at an episode's first step (steps 0 and 5)
    torch.testing.assert_close(history[:, 6, -1], torch.cat([td["observation"][:, 6],
                                                            td["action"][:, 5]], -1))
    assert td["is_init"][:, 5].all() and (history[:, 5, :, 89:] == 0).all()
    # the latent the policy planned from is the one training computes from the recording
    with torch.no_grad():
        offline = wm.encode_sequence(td["observation"], td["is_init"][..., 0], td["action"])
    torch.testing.assert_close(td["planner", "latent"], offline)
    # the losses read the actions too, and an env without the primer's key is refused
    batch = linear_system_batch(batch=4, time=8, obs_dim=89, action_dim=12)
    assert torch.isfinite(agent.pretrain_loss(batch)["loss_consistency"])
    bare = TransformedEnv(make_env("quadruped-flat", seed=0, max_episode_steps=5, num_envs=2),
                          InitTracker())
    with pytest.raises(KeyError, match="previous action"):
        bare.rollout(2, policy)
    # saved and loaded with the option
    path = agent.save(tmp_path / "agent.pt")
    loaded = SimDistAgent.load(path)
    assert loaded.world_model.encoder.action_dim == 12
    with torch.no_grad():
        torch.testing.assert_close(
            loaded.world_model.encode_sequence(td["observation"], td["is_init"][..., 0],
                                               td["action"]), offline)


def test_previous_action_latents_match_training_with_staggered_resets_and_actions_in_flight():
    torch.manual_seed(0)
    wm = SimDistWorldModel.build(6, 2, size="tiny", history=3, previous_action=True)
    agent = SimDistAgent(wm, SimDistConfig(horizon=3))
    policy = agent.policy(config=PlannerConfig(horizon=2, num_samples=8, num_elites=2,
                                               iterations=1, latency_compensation=2))
    B, T = 3, 9
    obs = torch.randn(B, T, 6)
    is_init = torch.zeros(B, T, dtype=torch.bool)
    is_init[:, 0] = True
    is_init[1, 2] = is_init[2, 5] = True  # episodes restart at different steps
    carried = {"history": torch.randn(B, 3, 8), "previous_action": torch.randn(B, 2),
               "pending_actions": torch.randn(B, 2, 2)}  # stale state: must not leak
    actions, latents = [], []
    for t in range(T):
        td = TensorDict({"observation": obs[:, t], "is_init": is_init[:, t, None],
                         "simdist": carried}, [B])
        td = policy(td)
        if t == 4:  # a wrapper sends another action: the next steps must encode that one
            td = SimDistPolicy.replace_action(td, -td["action"])
        actions.append(td["action"])
        latents.append(td["planner", "latent"])
        carried = td["next", "simdist"]
    with torch.no_grad():
        offline = wm.encode_sequence(obs, is_init, torch.stack(actions, 1))
    torch.testing.assert_close(torch.stack(latents, 1), offline)


def test_command_latents_encode_the_history_under_each_proposal_command():
    agent = SimDistAgent(SimDistWorldModel.build(5, 2, size="tiny", history=3,
                                                 previous_action=True))
    planner = PlannerConfig(horizon=2, num_samples=6, num_elites=2, iterations=1,
                            policy_fraction=0.5, proposal_commands=(0.25, 0.75))
    policy = agent.policy(config=planner)  # the command is the observation's last entry
    seen = []
    policy.planner.register_forward_pre_hook(lambda m, args: seen.append(args[0].clone()))
    obs = torch.randn(2, 5)
    previous = torch.randn(2, 2)
    policy(TensorDict({"observation": obs, "is_init": torch.ones(2, 1, dtype=torch.bool),
                       "simdist": {"previous_action": previous}}, [2]))
    other = seen[0]["proposal_latent"]
    assert other.shape == (2, 2, agent.world_model.latent_dim)
    for i, command in enumerate((0.25, 0.75)):
        # what the policy would encode had the observation said this command
        edited = obs.clone()
        edited[:, -1] = command
        direct = policy(TensorDict({"observation": edited,
                                    "is_init": torch.ones(2, 1, dtype=torch.bool),
                                    "simdist": {"previous_action": previous}}, [2]))
        torch.testing.assert_close(other[:, i], direct["planner", "latent"])
    with pytest.raises(ValueError, match="command_index"):
        agent.policy(config=planner, command_index=5)
