"""The Dreamer agent acts recurrently inside TorchRL rollouts and its updates learn."""

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs import InitTracker, TransformedEnv

from simdist.agents import DreamerAgent, DreamerConfig
from simdist.envs import make_env
from tests.synthetic import linear_system_batch


def _agent(state_dim=5, action_dim=1):
    torch.manual_seed(0)
    return DreamerAgent.for_state(state_dim, action_dim, DreamerConfig(size="tiny"))


def test_policy_carries_its_filter_state_and_resets_at_episode_starts():
    agent = _agent()
    env = TransformedEnv(make_env("cartpole-balance", seed=0, max_episode_steps=6), InitTracker())
    env.append_transform(agent.make_primer())
    td = env.rollout(14, agent.policy(explore=True), break_when_any_done=False)
    belief_in, belief_out = td["agent", "belief"], td["next", "agent", "belief"]
    starts = td["is_init"][:, 0]
    assert starts.nonzero().flatten().tolist() == [0, 6, 12]
    assert (belief_in[starts] == 0).all()  # reset by the primer at each episode start
    carried = ~starts[1:]
    assert torch.equal(belief_in[1:][carried], belief_out[:-1][carried])
    assert torch.equal(td["next", "agent", "prev_action"], td["action"])
    assert (td["action"].abs() <= 1).all()


def test_seeded_policy_is_reproducible_and_exploration_adds_noise():
    agent = _agent()
    env = TransformedEnv(make_env("cartpole-balance", seed=0), InitTracker())
    env.append_transform(agent.make_primer())

    def run(explore):
        torch.manual_seed(1)  # latent samples and exploration noise use torch's generator
        env.set_seed(0)
        return env.rollout(5, agent.policy(explore=explore))["action"]

    greedy = run(False)
    assert torch.equal(greedy, run(False))
    assert not torch.equal(run(True), greedy)


def test_updates_learn_the_world_model_and_keep_terms_finite():
    agent = _agent(state_dim=4, action_dim=2)
    batch = linear_system_batch(batch=16, time=10, obs_dim=4)
    first = agent.update(batch.clone())
    for _ in range(150):
        last = agent.update(batch.clone())
    assert last["loss_reconstruction"] < first["loss_reconstruction"] / 3
    assert all(torch.isfinite(torch.tensor(v)) for v in last.values())


def test_behaviour_updates_on_a_frozen_world_model_leave_it_unchanged():
    """update_behaviour: actor and critic learn from the posteriors the model loss wrote,
    the world model's weights stay bit for bit; a batch without posteriors is refused."""
    agent = _agent(state_dim=4, action_dim=2)
    batch = linear_system_batch(batch=8, time=6, obs_dim=4)
    with pytest.raises(KeyError, match="no \\('posterior', 'belief'\\)"):
        agent.update_behaviour(batch.clone())
    model = {k: v.clone() for k, v in agent.world_model.state_dict().items()}
    actor = [p.clone() for p in agent.actor.parameters()]
    critic = [p.clone() for p in agent.critic.parameters()]
    for _ in range(3):
        td = batch.clone()
        with torch.no_grad():
            agent.model_loss(td)
        out = agent.update_behaviour(td)
        assert torch.isfinite(out["loss_actor"]) and torch.isfinite(out["loss_critic"])
    assert all(torch.equal(v, agent.world_model.state_dict()[k]) for k, v in model.items())
    assert all(p.grad is None for p in agent.world_model.parameters())
    assert any(not torch.equal(a, b) for a, b in zip(actor, agent.actor.parameters()))
    assert any(not torch.equal(a, b) for a, b in zip(critic, agent.critic.parameters()))


def test_dreamer_v2_actor_explores_by_sampling_inside_the_box_and_learns():
    """DreamerConfig(actor_distribution="trunc_normal", exploration="sample"): collection
    draws from the actor (no added noise), evaluation takes its mode, and updates run."""
    torch.manual_seed(0)
    config = DreamerConfig(size="tiny", actor_distribution="trunc_normal", exploration="sample")
    agent = DreamerAgent.for_state(4, 2, config)
    assert agent.actor.kind == "trunc_normal"
    explore, greedy = agent.policy(explore=True), agent.policy(explore=False)
    assert (explore.sample, explore.noise) == (True, 0.0)
    assert (greedy.sample, greedy.noise) == (False, 0.0)
    obs = TensorDict({"state": torch.zeros(256, 4),
                      "is_init": torch.ones(256, 1, dtype=torch.bool)}, [256])
    torch.manual_seed(1)  # the same latent draws in both calls: the actor's draw differs
    sampled = explore(obs.clone())["action"]
    torch.manual_seed(1)
    mode = greedy(obs.clone())["action"]
    torch.manual_seed(1)
    assert torch.equal(greedy(obs.clone())["action"], mode)
    assert (sampled.abs() <= 1).all() and (sampled - mode).std(0).min() > 0.1
    batch = linear_system_batch(batch=8, time=10, obs_dim=4, action_dim=2)
    terms = agent.update(batch)
    assert all(torch.isfinite(torch.tensor(v)) for v in terms.values())


def test_reward_scale_weighs_the_world_models_reward_term():
    td = linear_system_batch(batch=2, time=5, obs_dim=4)
    losses = {}
    for scale in (1.0, 10.0):
        torch.manual_seed(0)
        agent = DreamerAgent.for_state(4, 2, DreamerConfig(size="tiny", reward_scale=scale))
        assert agent.model_loss.reward_scale == scale
        torch.manual_seed(1)
        losses[scale] = agent.model_loss(td.clone())
    torch.testing.assert_close(losses[10.0]["loss_reward"], 10 * losses[1.0]["loss_reward"])
    torch.testing.assert_close(losses[10.0]["loss_reconstruction"],
                               losses[1.0]["loss_reconstruction"])
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="reward_scale must be > 0"):
            DreamerConfig(reward_scale=bad)


def test_dreamer_config_refuses_unknown_actor_forms():
    for field, value in (("actor_distribution", "beta"), ("exploration", "epsilon"),
                         ("return_normalisation", "zscore"), ("actor_gradient", "pathwise"),
                         ("encoder", "resnet")):
        with pytest.raises(ValueError, match=f"unknown {field} '{value}'"):
            DreamerConfig(**{field: value})


def test_pixel_dreamers_read_their_image_with_the_configured_encoder(tmp_path):
    """``encoder="keypoints"``: both pixel Dreamers read the image with spatial-softmax
    keypoints (the state-recon one too), train on images, and a saved agent comes back
    with the same encoder; the default stays the CNN."""
    config = DreamerConfig(size="tiny", encoder="keypoints")
    td = TensorDict({"action": torch.zeros(2, 4, 1),
                     "is_init": torch.zeros(2, 4, 1, dtype=torch.bool),
                     "next": {"pixels": torch.randint(0, 255, (2, 4, 64, 64, 3),
                                                      dtype=torch.uint8),
                              "state": torch.zeros(2, 4, 5), "reward": torch.zeros(2, 4, 1),
                              "terminated": torch.zeros(2, 4, 1, dtype=torch.bool)}}, [2, 4])
    for agent in (DreamerAgent.for_pixels(1, config),
                  DreamerAgent.for_pixels_state_recon(1, 5, config)):
        assert agent.world_model.encoder.arch == "keypoints"
        assert torch.isfinite(torch.tensor(agent.update(td.clone())["loss_reconstruction"]))
        loaded = DreamerAgent.load(agent.save(tmp_path / "agent.pt"))
        assert loaded.world_model.encoder.arch == "keypoints"
        torch.testing.assert_close(loaded.world_model.encoder.state_dict(),
                                   agent.world_model.encoder.state_dict())
    assert DreamerAgent.for_pixels(1, DreamerConfig(size="tiny")).world_model.encoder.arch == \
        "dreamer"


def test_return_normalisation_is_kept_through_updates_checkpoints_and_resumes(tmp_path):
    """DreamerConfig(return_normalisation="percentile"): updates report and move the scale;
    a saved agent and a training state dict carry the running percentiles, so a loaded or
    resumed agent divides by the same scale; the default has none."""
    torch.manual_seed(0)
    agent = DreamerAgent.for_state(4, 2, DreamerConfig(size="tiny",
                                                       return_normalisation="percentile"))
    batch = linear_system_batch(batch=8, time=10, obs_dim=4, action_dim=2)
    terms = [agent.update(batch.clone()) for _ in range(3)]
    assert all(t["return_scale"] >= 1 for t in terms)
    scale = agent.behaviour_loss.return_scale
    assert int(scale.count) == 3
    loaded = DreamerAgent.load(agent.save(tmp_path / "agent.pt"))
    assert loaded.config.return_normalisation == "percentile"
    for name in ("low", "high", "count"):
        assert torch.equal(getattr(loaded.behaviour_loss.return_scale, name),
                           getattr(scale, name))
    resumed = DreamerAgent.for_state(4, 2, agent.config)
    resumed.load_state_dict(agent.state_dict())
    assert torch.equal(resumed.behaviour_loss.return_scale.high, scale.high)
    plain = _agent(state_dim=4, action_dim=2)
    assert plain.behaviour_loss.return_scale is None
    assert "return_scale" not in plain.state_dict() and "return_scale" not in plain.weights()
    assert "return_scale" not in plain.update(batch.clone())


def test_state_recon_standardises_its_target_through_updates_checkpoints_and_resumes(tmp_path):
    """DreamerConfig(standardise_reconstruction=True): State Recon.'s loss standardises the
    state by running statistics that updates move, saved agents and training state dicts
    carry; image-decoding and default agents have none."""
    torch.manual_seed(0)
    config = DreamerConfig(size="tiny", standardise_reconstruction=True)
    agent = DreamerAgent.for_pixels_state_recon(1, 5, config)
    td = TensorDict({"action": torch.zeros(2, 4, 1),
                     "is_init": torch.zeros(2, 4, 1, dtype=torch.bool),
                     "next": {"pixels": torch.randint(0, 255, (2, 4, 64, 64, 3),
                                                      dtype=torch.uint8),
                              "state": 3 + 2 * torch.randn(2, 4, 5),
                              "reward": torch.zeros(2, 4, 1),
                              "terminated": torch.zeros(2, 4, 1, dtype=torch.bool)}}, [2, 4])
    agent.update(td.clone())
    agent.update(td.clone())
    standardiser = agent.model_loss.reconstruction_standardiser
    assert int(standardiser.count) == 2 and standardiser.mean.shape == (5,)
    assert float(standardiser.mean.mean()) == pytest.approx(3.0, abs=1.0)
    loaded = DreamerAgent.load(agent.save(tmp_path / "agent.pt"))
    assert loaded.config.standardise_reconstruction
    for name in ("mean", "var", "count"):
        assert torch.equal(getattr(loaded.model_loss.reconstruction_standardiser, name),
                           getattr(standardiser, name))
    resumed = DreamerAgent.for_pixels_state_recon(1, 5, config)
    resumed.load_state_dict(agent.state_dict())
    assert torch.equal(resumed.model_loss.reconstruction_standardiser.var, standardiser.var)
    # image decoders ignore the option; the default reconstructs the raw state
    assert DreamerAgent.for_pixels(1, config).model_loss.reconstruction_standardiser is None
    plain = DreamerAgent.for_pixels_state_recon(1, 5, DreamerConfig(size="tiny"))
    assert plain.model_loss.reconstruction_standardiser is None
    assert "reconstruction_standardiser" not in plain.weights()
