"""The latent MPPI planner on problems whose optimum is known."""

import math

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule

from simdist.modules import SimDistWorldModel
from simdist.modules.planner import LatentMPPIPlanner, PlannerConfig, colored_noise


def _plan(planner, latent, **extra):
    return planner(TensorDict({"latent": latent, **extra}, [latent.shape[0]]))


def test_bandit_horizon_one_finds_each_envs_optimum():
    best = torch.tensor([[0.7], [-0.3], [0.1]])
    # latent carries the optimum; reward peaks at a = latent
    planner = LatentMPPIPlanner(lambda z, a: z, lambda z, a: -(a - z).pow(2).sum(-1, keepdim=True),
                                None, action_dim=1, seed=0,
                                config=PlannerConfig(horizon=1, num_samples=256, num_elites=16,
                                                     iterations=6, init_std=1.0, max_std=1.0))
    out = _plan(planner, best.clone())
    torch.testing.assert_close(out["action"], best, atol=0.03, rtol=0)


def test_point_mass_moves_to_target_at_full_speed_then_stops():
    target = 1.0
    dynamics = lambda z, a: z + 0.1 * a  # noqa: E731
    reward = lambda z, a: -(dynamics(z, a) - target).pow(2)  # noqa: E731
    cfg = PlannerConfig(horizon=12, num_samples=256, num_elites=32, iterations=6)
    planner = LatentMPPIPlanner(dynamics, reward, None, action_dim=1, config=cfg, seed=0)
    far = _plan(planner, torch.tensor([[0.0], [2.0]]))
    assert far["action"][0] > 0.9 and far["action"][1] < -0.9  # bang towards the target
    planner.reset()
    z = torch.tensor([[0.0]])
    for _ in range(25):  # closed loop with warm start
        z = dynamics(z, _plan(planner, z)["action"])
    assert abs(z.item() - target) < 0.05


def test_terminal_value_is_used():
    # Zero reward everywhere; only V(z_H) = z_H tells the planner to go up.
    planner = LatentMPPIPlanner(lambda z, a: z + a, lambda z, a: torch.zeros_like(z), lambda z: z,
                                action_dim=1, seed=0,
                                config=PlannerConfig(horizon=3, num_samples=128, num_elites=8))
    assert (_plan(planner, torch.zeros(4, 1))["action"] > 0.5).all()
    no_value = LatentMPPIPlanner(lambda z, a: z + a, lambda z, a: torch.zeros_like(z), None,
                                 action_dim=1, seed=0,
                                 config=PlannerConfig(horizon=3, num_samples=128, num_elites=8))
    assert _plan(no_value, torch.zeros(4, 1))["action"].abs().mean() < 0.5
    # value_weight scales the terminal value: 0 plans exactly as with no value head
    plans = [_plan(LatentMPPIPlanner(
        lambda z, a: z + a, lambda z, a: torch.zeros_like(z), value, action_dim=1, seed=0,
        config=PlannerConfig(horizon=3, num_samples=128, num_elites=8, value_weight=w)),
        torch.zeros(4, 1))["action"] for value, w in ((lambda z: z, 0.0), (None, 1.0))]
    torch.testing.assert_close(*plans)


def test_value_lambda_scores_a_lambda_return_computed_by_hand():
    # z_t = t (+1 per step), r_t = 1, V(z) = 10 z: with H = 2, gamma = 0.5, lambda = 0.25,
    # value_weight = 2: G_2 = 2 V(2) = 40; G_1 = 1 + 0.5 (0.75 * 2 V(2) + 0.25 G_2) = 21;
    # G_0 = 1 + 0.5 (0.75 * 2 V(1) + 0.25 G_1) = 1 + 0.5 (15 + 5.25) = 11.125.
    def planner(lam):
        return LatentMPPIPlanner(lambda z, a: z + 1, lambda z, a: torch.ones_like(z),
                                 lambda z: 10 * z, action_dim=1, seed=0,
                                 config=PlannerConfig(horizon=2, num_samples=4, num_elites=2,
                                                      gamma=0.5, value_weight=2.0,
                                                      value_lambda=lam))
    actions = torch.zeros(1, 3, 2, 1)
    scores, rewards, values = planner(0.25)._evaluate(torch.zeros(1, 1), actions)
    torch.testing.assert_close(scores, torch.full((1, 3), 11.125))
    torch.testing.assert_close(values, torch.full((1, 3), 20.0))  # still the terminal V
    # lambda = 1 is the terminal-value score: 1 + 0.5 + 0.25 * 2 * 20 = 11.5
    torch.testing.assert_close(planner(1.0)._evaluate(torch.zeros(1, 1), actions)[0],
                               torch.full((1, 3), 11.5))
    # lambda = 0: one-step bootstraps only: G_0 = 1 + 0.5 * 2 V(1) = 11
    torch.testing.assert_close(planner(0.0)._evaluate(torch.zeros(1, 1), actions)[0],
                               torch.full((1, 3), 11.0))


def test_value_every_reads_every_kth_value_with_lambda_to_the_k():
    # z_t = t, r_t = 1, V(z) = 10 z, H = 3, gamma = 0.5, value_weight = 2, lambda = 0.5,
    # k = 2: values at z_2 only (mixed with lambda^2 = 0.25) and the terminal one:
    # G_3 = 2 V(3) = 60; G_2 = 1 + 0.5 G_3 = 31; G_1 = 1 + 0.5 (0.75 * 2 V(2) + 0.25 G_2)
    # = 19.875; G_0 = 1 + 0.5 G_1 = 10.9375.
    def planner(lam, every):
        return LatentMPPIPlanner(lambda z, a: z + 1, lambda z, a: torch.ones_like(z),
                                 lambda z: 10 * z, action_dim=1, seed=0,
                                 config=PlannerConfig(horizon=3, num_samples=4, num_elites=2,
                                                      gamma=0.5, value_weight=2.0,
                                                      value_lambda=lam, value_every=every))
    actions, start = torch.zeros(1, 3, 3, 1), torch.zeros(1, 1)
    torch.testing.assert_close(planner(0.5, 2)._evaluate(start, actions)[0],
                               torch.full((1, 3), 10.9375))
    # every step (k = 1): G_2 = 31; G_1 = 1 + 0.5 (0.5 * 40 + 0.5 * 31) = 18.75;
    # G_0 = 1 + 0.5 (0.5 * 20 + 0.5 * 18.75) = 10.6875
    torch.testing.assert_close(planner(0.5, 1)._evaluate(start, actions)[0],
                               torch.full((1, 3), 10.6875))
    # k >= H reads no value along the plan: the terminal-value score 1.75 + 0.125 * 60
    for every in (3, 7):
        torch.testing.assert_close(planner(0.5, every)._evaluate(start, actions)[0],
                                   planner(1.0, 1)._evaluate(start, actions)[0])
    torch.testing.assert_close(planner(1.0, 1)._evaluate(start, actions)[0],
                               torch.full((1, 3), 9.25))


def test_warm_start_shifts_the_previous_plan_and_resets_per_env():
    cfg = PlannerConfig(horizon=4, num_samples=32, num_elites=4, iterations=1)
    planner = LatentMPPIPlanner(lambda z, a: z, lambda z, a: -(a - 0.5).pow(2), None, 1, cfg, seed=0)
    first = _plan(planner, torch.zeros(2, 1))["planner", "mean"].clone()
    is_init = torch.tensor([[False], [True]])
    start = planner._initial_mean(torch.zeros(2, 1), is_init)
    torch.testing.assert_close(start[0, :3], first[0, 1:])
    assert torch.equal(start[0, 3], torch.zeros(1)) and torch.equal(start[1], torch.zeros(4, 1))
    no_warm = LatentMPPIPlanner(lambda z, a: z, lambda z, a: -(a - 0.5).pow(2), None, 1,
                                PlannerConfig(horizon=4, num_samples=32, num_elites=4,
                                              iterations=1, warm_start=False), seed=0)
    _plan(no_warm, torch.zeros(2, 1))
    assert torch.equal(no_warm._initial_mean(torch.zeros(2, 1), None), torch.zeros(2, 4, 1))


def test_policy_proposals_find_what_sampling_cannot():
    # Reward only for actions within 0.01 of 0.9 at every step; sampling is tight around 0.
    reward = lambda z, a: (((a - 0.9).abs() < 0.01).float() - 0.0).sum(-1, keepdim=True)  # noqa: E731
    cfg = PlannerConfig(horizon=3, num_samples=100, num_elites=5, iterations=2, init_std=0.05,
                        min_std=0.01, max_std=0.05, policy_fraction=0.1, policy_noise=0.001)
    policy = lambda z: torch.full((z.shape[0], 1), 0.9)  # noqa: E731
    with_policy = LatentMPPIPlanner(lambda z, a: z, reward, None, 1, cfg, policy=policy, seed=0)
    without = LatentMPPIPlanner(lambda z, a: z, reward, None, 1, cfg, seed=0)
    assert abs(_plan(with_policy, torch.zeros(1, 1))["action"].item() - 0.9) < 0.01
    assert abs(_plan(without, torch.zeros(1, 1))["action"].item()) < 0.3


@pytest.mark.parametrize("reward", [
    lambda z, a: torch.zeros(z.shape[0], 1),                     # all scores equal
    lambda z, a: torch.full((z.shape[0], 1), -math.inf),          # all -inf
    lambda z, a: torch.where(a > 0, torch.nan, 1.0).sum(-1, keepdim=True),  # some NaN
])
def test_degenerate_scores_never_give_nan(reward):
    planner = LatentMPPIPlanner(lambda z, a: z, reward, None, 2,
                                PlannerConfig(horizon=3, num_samples=16, num_elites=4), seed=0)
    out = _plan(planner, torch.zeros(3, 2))
    assert torch.isfinite(out["action"]).all() and torch.isfinite(out["planner", "mean"]).all()
    assert (out["action"].abs() <= 1).all()


def test_seeded_planner_is_deterministic_and_bounded():
    torch.manual_seed(0)
    wm = SimDistWorldModel.build(obs_dim=4, action_dim=3, size="tiny")
    cfg = PlannerConfig(horizon=4, num_samples=32, num_elites=4, action_low=-0.5, action_high=0.5)
    latent = torch.rand(2, wm.latent_dim)
    a = _plan(LatentMPPIPlanner.from_world_model(wm, cfg, seed=3), latent)
    b = _plan(LatentMPPIPlanner.from_world_model(wm, cfg, seed=3), latent)
    assert torch.equal(a["action"], b["action"])
    assert (a["action"].abs() <= 0.5).all()
    assert a["planner", "elite_actions"].shape == (2, 4, 4, 3)
    assert a["planner", "rewards"].shape == (2, 4)


def test_accepts_tensordict_modules_and_unbatched_latents():
    dyn = TensorDictModule(lambda z, a: z + 0.1 * a, in_keys=["latent", "action"], out_keys=["latent"])
    rew = TensorDictModule(lambda z, a: -(z - 1).pow(2), in_keys=["latent", "action"], out_keys=["reward"])
    planner = LatentMPPIPlanner(dyn, rew, None, 1, PlannerConfig(horizon=4), seed=0)
    out = planner(TensorDict({"latent": torch.zeros(1)}, []))
    assert out["action"].shape == (1,) and out["action"].item() > 0.5


@pytest.mark.parametrize("kwargs, message", [
    (dict(num_samples=8, num_elites=16), "num_elites \\(16\\) must be <= num_samples"),
    (dict(init_std=-1.0), "stds must satisfy"),
    (dict(horizon=0), "horizon must be >= 1"),
    (dict(temperature=0.0), "temperature"),
    (dict(action_low=1.0, action_high=-1.0), "action bounds inverted"),
    (dict(value_weight=-0.5), "value_weight must be >= 0"),
    (dict(noise_beta=-1.0), "noise_beta must be >= 0"),
    (dict(value_lambda=1.5), "value_lambda must lie in"),
    (dict(value_every=0), "value_every must be >= 1"),
    (dict(value_every=1.5), "value_every must be an integer"),
    (dict(value_lambda=math.nan), "value_lambda must be a finite number"),
    (dict(noise_beta=math.nan), "noise_beta must be a finite number"),
    (dict(precision="float16"), "precision must be one of"),
])
def test_bad_configs_are_clear_errors(kwargs, message):
    with pytest.raises(ValueError, match=message):
        PlannerConfig(**kwargs)


def test_missing_latent_key_is_a_clear_error():
    planner = LatentMPPIPlanner(lambda z, a: z, lambda z, a: z, None, 1)
    with pytest.raises(KeyError, match="no 'latent'"):
        planner(TensorDict({"obs": torch.zeros(2, 1)}, [2]))


def test_per_dimension_action_bounds():
    low, high = torch.tensor([-1.0, -0.2]), torch.tensor([1.1, 0.3])
    planner = LatentMPPIPlanner(lambda z, a: z, lambda z, a: a.sum(-1, keepdim=True), None, 2,
                                PlannerConfig(horizon=2, num_samples=64, num_elites=8,
                                              iterations=4), seed=0, action_bounds=(low, high))
    action = _plan(planner, torch.zeros(1, 1))["action"][0]
    assert (action >= low).all() and (action <= high).all()
    torch.testing.assert_close(action, high, atol=0.05, rtol=0)  # reward grows with a
    with pytest.raises(ValueError, match="action_bounds"):
        LatentMPPIPlanner(lambda z, a: z, lambda z, a: z, None, 2,
                          action_bounds=(torch.zeros(2), torch.zeros(2)))


@pytest.mark.parametrize("kwargs, message", [
    (dict(num_samples=64.5), "num_samples must be an integer, got 64.5"),
    (dict(horizon=5.0), "horizon must be an integer"),
    (dict(iterations=True), "iterations must be an integer"),
    (dict(policy_noise=math.nan), "policy_noise must be a finite number, got nan"),
    (dict(policy_noise=math.inf), "policy_noise must be a finite number"),
    (dict(max_std=math.inf), "max_std must be a finite number"),
    (dict(action_high=math.inf), "action_high must be a finite number"),
])
def test_non_integer_counts_and_non_finite_values_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        PlannerConfig(**kwargs)


def _point_mass(**kwargs):
    return LatentMPPIPlanner(lambda z, a: z + 0.1 * a, lambda z, a: -(z - 1).pow(2).sum(
        -1, keepdim=True), None, 1, PlannerConfig(horizon=3, num_samples=16, num_elites=4),
        seed=0, **kwargs)


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_non_finite_latent_is_refused_naming_the_key(value):
    planner = _point_mass(latent_key="z")
    latent = torch.zeros(2, 1)
    latent[1] = value
    with pytest.raises(ValueError, match="'z' contains NaN or inf"):
        planner(TensorDict({"z": latent}, [2]))
    with pytest.raises(ValueError, match="contains NaN or inf"):  # all of it, unbatched too
        planner(TensorDict({"z": torch.full((1,), value)}, []))


def test_wrong_latent_size_and_is_init_batch_fail_at_the_boundary():
    torch.manual_seed(0)
    wm = SimDistWorldModel.build(obs_dim=4, action_dim=3, size="tiny")
    planner = LatentMPPIPlanner.from_world_model(wm, PlannerConfig(horizon=2, num_samples=8,
                                                                   num_elites=2))
    with pytest.raises(ValueError, match=f"'latent' has size 5, the models expect "
                                         f"{wm.latent_dim}"):
        _plan(planner, torch.zeros(2, 5))
    with pytest.raises(ValueError, match="'is_init' must hold one flag per environment \\(2"):
        planner(TensorDict({"latent": torch.zeros(2, wm.latent_dim),  # unbatched TensorDict
                            "is_init": torch.zeros(3, 1, dtype=torch.bool)}, []))
    with pytest.raises(TypeError, match="'latent' must be floating point"):
        _plan(planner, torch.zeros(2, wm.latent_dim, dtype=torch.long))
    # Models of unknown latent size: the failure still names the key and the shape.
    plain = LatentMPPIPlanner(lambda z, a: z @ torch.ones(4, 4), lambda z, a: z[:, :1], None, 1,
                              PlannerConfig(horizon=2, num_samples=8, num_elites=2))
    with pytest.raises(RuntimeError, match="planning from 'latent' of shape \\(2, 5\\)"):
        _plan(plain, torch.zeros(2, 5))


def _reference_plan(planner, latent, mean, sample_noise, policy_noise):
    """MPPI as written in docs/methods.md 1.4: every iteration rescores all candidates,
    proposals included (what the planner did before it scored the proposals once)."""
    c = planner.config
    proposals = planner._policy_proposals(latent, policy_noise)[0]
    std = torch.full_like(mean, c.init_std)
    for i in range(c.iterations):
        actions = (mean[:, None] + std[:, None] * sample_noise[i]).clamp(-1, 1)
        actions = torch.cat([proposals, actions], 1)
        scores, _, _ = planner._evaluate(latent, actions)
        elite_scores, index = scores.topk(c.num_elites, dim=1)
        elites = actions.gather(1, index[..., None, None].expand(-1, -1, *actions.shape[2:]))
        spread = (elite_scores[:, :1] - elite_scores[:, -1:]).clamp_min(1e-6)
        w = torch.softmax((elite_scores - elite_scores[:, :1]) / (spread * c.temperature), 1)
        mean = (w[..., None, None] * elites).sum(1).clamp(-1, 1)
        std = (w[..., None, None] * (elites - mean[:, None]).pow(2)).sum(1).sqrt().clamp(
            c.min_std, c.max_std)
    return mean, std, elites


def test_proposals_scored_once_plan_as_rescoring_them_every_iteration():
    torch.manual_seed(0)
    wm = SimDistWorldModel.build(obs_dim=7, action_dim=3, size="tiny")
    cfg = PlannerConfig(horizon=4, num_samples=24, num_elites=6, iterations=3,
                        policy_fraction=0.5, policy_noise=0.3)
    planner = LatentMPPIPlanner.from_world_model(wm, cfg, seed=0)
    B, P, A = 3, cfg.num_policy, 3
    latent = torch.randn(B, wm.latent_dim)
    mean = torch.zeros(B, cfg.horizon, A)
    sample_noise = torch.randn(cfg.iterations, B, cfg.num_samples - P, cfg.horizon, A)
    policy_noise = torch.randn(B, P, cfg.horizon, A)
    with torch.no_grad():
        actions, scores, rewards, values = planner._policy_proposals(latent, policy_noise)
        # the scores gathered along the proposing rollout are a fresh evaluation's
        for got, want in zip((scores, rewards, values), planner._evaluate(latent, actions)):
            torch.testing.assert_close(got, want)
        got = planner._plan(latent, mean, sample_noise, policy_noise)
        want = _reference_plan(planner, latent, mean, sample_noise, policy_noise)
    for g, w in zip((got[0], got[1], got[4]), want):
        torch.testing.assert_close(g, w)


def test_all_samples_from_the_policy_prior():
    # policy_fraction rounds to every sample: no random candidates, the proposals alone
    cfg = PlannerConfig(horizon=2, num_samples=8, num_elites=2, iterations=2,
                        policy_fraction=0.99, policy_noise=0.0)
    assert cfg.num_policy == cfg.num_samples
    planner = LatentMPPIPlanner(lambda z, a: z, lambda z, a: -(a - 0.4).pow(2), None, 1, cfg,
                                policy=lambda z: torch.full((z.shape[0], 1), 0.4), seed=0)
    torch.testing.assert_close(_plan(planner, torch.zeros(2, 1))["action"],
                               torch.full((2, 1), 0.4))


def test_buffers_start_on_the_models_device():
    # A planner built from a model already on another device must not keep its action bounds
    # on the CPU (on CUDA that failed inside the first clamp; found on an H100). The "meta"
    # device stands in for CUDA on CPU-only machines.
    wm = SimDistWorldModel.build(obs_dim=5, action_dim=2, size="tiny").to("meta")
    planner = LatentMPPIPlanner.from_world_model(wm, PlannerConfig(horizon=2, num_samples=8,
                                                                   num_elites=2))
    assert {b.device.type for b in planner.buffers()} == {"meta"}
    # without models (plain callables) the bounds stay where they were made
    free = LatentMPPIPlanner(lambda z, a: z, lambda z, a: z.sum(-1, keepdim=True), None,
                             action_dim=2)
    assert free.action_low.device.type == "cpu"


def test_white_noise_is_returned_unchanged():
    white = torch.randn(3, 8, 2)
    assert colored_noise(white, 0.0) is white


@pytest.mark.parametrize("n", [5, 8, 20])
def test_colored_noise_has_the_hand_computed_spectrum_and_unit_variance(n):
    # A unit impulse at step 0 filtered by the colouring gives the filter's impulse response;
    # its DFT must be the amplitude f^(-beta/2) (lowest frequency 1/n for f = 0), scaled so
    # that the mean squared amplitude over the full spectrum is 1 (unit variance per step).
    beta = 2.0
    impulse = torch.zeros(n, 1, dtype=torch.float64)
    impulse[0] = 1.0
    response = colored_noise(impulse, beta, dim=0)[:, 0]
    freqs = [max(min(k, n - k) / n, 1 / n) for k in range(n)]
    amplitude = torch.tensor([f ** (-beta / 2) for f in freqs], dtype=torch.float64)
    amplitude = amplitude / amplitude.pow(2).mean().sqrt()
    torch.testing.assert_close(torch.fft.fft(response).real, amplitude)
    torch.testing.assert_close(torch.fft.fft(response).imag, torch.zeros(n, dtype=torch.float64))
    # Statistically: every step stays N(0, 1), neighbouring steps become correlated.
    x = colored_noise(torch.randn(20000, n, 2, generator=torch.Generator().manual_seed(0)), beta)
    torch.testing.assert_close(x.std(dim=(0, 2)), torch.ones(n), atol=0.03, rtol=0)
    assert (x[:, 1:] * x[:, :-1]).mean() > 0.3


def test_colored_noise_survives_a_very_large_beta():
    x = colored_noise(torch.randn(4000, 20, 1, generator=torch.Generator().manual_seed(0)), 500.0)
    assert torch.isfinite(x).all()
    torch.testing.assert_close(x.std(), torch.tensor(1.0), atol=0.05, rtol=0)


def test_planner_samples_colored_sequences():
    # Zero reward: the final plan is the weighted mean of the elites, i.e. of the sampled
    # noise; with beta = 2 its consecutive steps move together, with white noise they do not.
    def plan(beta):
        planner = LatentMPPIPlanner(lambda z, a: z, lambda z, a: torch.zeros_like(z[..., :1]),
                                    None, 1, PlannerConfig(horizon=16, num_samples=8,
                                                           num_elites=1, iterations=1,
                                                           noise_beta=beta, init_std=0.5,
                                                           max_std=0.5), seed=0)
        return _plan(planner, torch.zeros(512, 1))["planner", "mean"][..., 0]
    def lag1(x):
        x = x - x.mean()
        return float((x[:, 1:] * x[:, :-1]).mean() / x.pow(2).mean())
    assert lag1(plan(2.0)) > 0.5 and abs(lag1(plan(0.0))) < 0.1


@pytest.mark.parametrize("steps", [1, 3])
def test_policy_noise_only_on_the_first_steps(steps):
    # Every sample a proposal (policy_fraction rounds to all): with policy_noise_steps = k
    # each elite is the prior's action + noise on steps < k and exactly the prior after.
    cfg = PlannerConfig(horizon=6, num_samples=16, num_elites=4, iterations=1,
                        policy_fraction=0.99, policy_noise=0.3, policy_noise_steps=steps)
    prior = lambda z: torch.full((z.shape[0], 2), 0.2)  # noqa: E731
    planner = LatentMPPIPlanner(lambda z, a: z, lambda z, a: -a.pow(2).sum(-1, keepdim=True),
                                None, 2, cfg, policy=prior, seed=0)
    elites = _plan(planner, torch.zeros(3, 1))["planner", "elite_actions"]
    assert elites.shape == (3, 4, 6, 2)
    torch.testing.assert_close(elites[:, :, steps:], torch.full_like(elites[:, :, steps:], 0.2))
    assert (elites[:, :, :steps] - 0.2).abs().min() > 0  # the first steps are perturbed
    with pytest.raises(ValueError, match="policy_noise_steps must be >= 0"):
        PlannerConfig(policy_noise_steps=-1)


def test_bfloat16_planning_runs_the_models_in_bfloat16_and_returns_float32():
    torch.manual_seed(0)
    wm = SimDistWorldModel.build(10, 3, size="tiny")
    seen = []
    hook = wm.dynamics.net[0].register_forward_hook(lambda m, i, o: seen.append(o.dtype))
    latent = torch.randn(4, wm.latent_dim)
    for precision, dtype in (("none", torch.float32), ("bfloat16", torch.bfloat16)):
        seen.clear()
        cfg = PlannerConfig(horizon=4, num_samples=32, num_elites=4, iterations=2,
                            precision=precision)
        out = _plan(LatentMPPIPlanner.from_world_model(wm, cfg, seed=0), latent)
        assert set(seen) == {dtype}  # every candidate step went through the dynamics in it
        for key in ("action", ("planner", "mean"), ("planner", "std"), ("planner", "rewards"),
                    ("planner", "value"), ("planner", "elite_actions")):
            assert out[key].dtype == torch.float32 and torch.isfinite(out[key]).all(), key
        assert out["action"].abs().max() <= 1
    hook.remove()


def test_bfloat16_planning_still_finds_the_optimum():
    # The bandit above with the optimum read through a Linear layer, which autocast runs in
    # bfloat16 (8 significant bits: 0.7 is held to ~0.003).
    best = torch.tensor([[0.7], [-0.3], [0.1]])
    read = torch.nn.Linear(1, 1, bias=False)
    torch.nn.init.ones_(read.weight)
    cfg = PlannerConfig(horizon=1, num_samples=256, num_elites=16, iterations=6, init_std=1.0,
                        max_std=1.0, precision="bfloat16")
    planner = LatentMPPIPlanner(lambda z, a: z, lambda z, a: -(a - read(z)).pow(2).sum(-1, keepdim=True),
                                None, action_dim=1, seed=0, config=cfg)
    out = _plan(planner, best.clone())
    torch.testing.assert_close(out["action"], best, atol=0.03, rtol=0)


def test_bfloat16_planning_runs_the_terminal_value_in_float32():
    # The value decides most of the ranking and bfloat16 rounds ~80 in steps of 0.5: the
    # value head alone is outside autocast, its input the float32 latent.
    torch.manual_seed(0)
    wm = SimDistWorldModel.build(10, 3, size="tiny")
    seen = {"value": [], "reward": []}
    hooks = [wm.value_head.register_forward_hook(lambda m, i, o: seen["value"].append(o.dtype)),
             wm.reward_head.register_forward_hook(lambda m, i, o: seen["reward"].append(o.dtype))]
    cfg = PlannerConfig(horizon=3, num_samples=16, num_elites=4, iterations=2, precision="bfloat16")
    _plan(LatentMPPIPlanner.from_world_model(wm, cfg, seed=0), torch.randn(2, wm.latent_dim))
    assert set(seen["value"]) == {torch.float32} and set(seen["reward"]) == {torch.bfloat16}
    for hook in hooks:
        hook.remove()


def _command_world():
    """Latent ``[position, command]``: the prior walks the way the command's sign says,
    the reward pays forward position whatever the latent's command entry."""
    dynamics = lambda z, a: torch.cat([z[:, :1] + 0.1 * a, z[:, 1:]], -1)  # noqa: E731
    reward = lambda z, a: z[:, :1]  # noqa: E731
    prior = lambda z: torch.sign(z[:, 1:])  # noqa: E731
    config = PlannerConfig(horizon=3, num_samples=10, num_elites=4, iterations=1,
                           policy_fraction=0.9, policy_noise=0.0, warm_start=False)
    return LatentMPPIPlanner(dynamics, reward, None, action_dim=1, config=config,
                             policy=prior, seed=0)


def test_proposals_from_other_latents_are_scored_from_the_own_latent():
    planner = _command_world()
    own = torch.tensor([[0.0, -1.0]])  # this command's prior walks backwards
    other = torch.tensor([[[0.0, 1.0], [0.0, -1.0]]])  # [B, C, L]: one forwards, one back
    out = _plan(planner, own, proposal_latent=other)
    elites = out["planner", "elite_actions"][0]
    # 9 proposals in 3 groups (own, forward, back): the 3 forward ones are all +1 ...
    assert (elites[:3] == 1).all() and out["action"][0, 0] > 0
    # ... and are scored from the own latent: rewards z_t[0] = 0, 0.1, 0.2 along +1
    torch.testing.assert_close(out["planner", "rewards"][0], torch.tensor([0.0, 0.1, 0.2]))
    without = _plan(_command_world(), own)
    assert (without["planner", "elite_actions"][0, :3] != 1).any()


def test_proposal_latents_equal_to_the_own_latent_change_nothing_but_the_noise_groups():
    torch.manual_seed(0)
    model = SimDistWorldModel.build(6, 2, size="tiny", history=1)
    config = PlannerConfig(horizon=4, num_samples=12, num_elites=3, iterations=2,
                           policy_fraction=0.5, policy_noise=0.0)
    latent = model.encode(torch.randn(3, 1, 6))
    plans = [_plan(LatentMPPIPlanner.from_world_model(model, config, seed=0), latent, **extra)
             for extra in ({}, {"proposal_latent": latent[:, None].repeat(1, 2, 1)})]
    # without noise on the prior, the same latent proposes the same sequence in any group
    torch.testing.assert_close(plans[0]["action"], plans[1]["action"])


@pytest.mark.parametrize("other, message", [
    (torch.zeros(2, 3, 5), r"must be \[B, C, L\]"),
    (torch.zeros(2, 2), r"must be \[B, C, L\]"),  # no C
    (torch.full((2, 1, 2), float("nan")), "NaN or inf"),
])
def test_bad_proposal_latents_fail_at_the_boundary(other, message):
    with pytest.raises(ValueError, match=message):
        _plan(_command_world(), torch.zeros(2, 2), proposal_latent=other)


def test_proposal_commands_are_checked_and_kept_as_a_tuple():
    assert PlannerConfig(proposal_commands=[0.25, 1]).proposal_commands == (0.25, 1.0)
    with pytest.raises(ValueError, match="proposal_commands"):
        PlannerConfig(proposal_commands=(0.5, float("inf")))
