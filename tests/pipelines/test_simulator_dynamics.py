import pytest
import torch
from tensordict import TensorDict

from simdist.envs import make_env
from simdist.pipelines import SimulatorDynamics


@pytest.mark.parametrize("task,target", [("quadruped-flat", "slippery_slope"),
                                          ("quadruped-terrain", "sim")])
def test_a_copy_steps_exactly_as_the_world_does(task, target):
    """The ceiling is only a ceiling if its model is the world: a candidate stepped from a
    world's state must give that world's next observation to the bit (episode draws
    included: dynamics, command, the per-episode incline of the terrain task)."""
    env = make_env(task, num_envs=2, target=target, seed=3)
    td = env.reset()
    for _ in range(5):  # leave the initial state: contacts, velocities, warm starts
        td = env.step(td.set("action", torch.rand(2, 12) * 2 - 1))["next"]
    dynamics = SimulatorDynamics(env.sims, history=3, obs_dim=89)
    dynamics.sync()
    history = torch.randn(2, 3, 89)
    z = dynamics.latent(history)
    actions = torch.rand(2, 12) * 2 - 1
    predicted = dynamics(z, actions.double())
    # planning steps the copies only: the worlds are where they were
    assert torch.equal(dynamics.latent(history), z)
    real = env.step(TensorDict({"action": actions}, [2]))["next", "observation"]
    assert torch.equal(dynamics.history_of(predicted)[:, -1], real)
    # the history shifts by one step and the world index rides along unchanged
    assert torch.equal(dynamics.history_of(predicted)[:, :-1], history[:, 1:])
    assert torch.equal(predicted[:, 0], z[:, 0])


def test_refuses_what_it_cannot_copy():
    laggy = make_env("quadruped-flat", num_envs=1, target="laggy", seed=0)
    laggy.reset()
    with pytest.raises(ValueError, match="action latency"):
        SimulatorDynamics(laggy.sims, history=2, obs_dim=89).sync()
    with pytest.raises(ValueError, match="encoder reads 10"):
        SimulatorDynamics(laggy.sims, history=2, obs_dim=10)
    with pytest.raises(ValueError, match="robot task"):
        SimulatorDynamics(make_env("cartpole-balance", num_envs=1).sims, history=2, obs_dim=5)


def test_a_step_pairs_the_new_observation_with_the_action_just_applied():
    # an encoder that reads the previous action: each history step is [o_t, a_{t-1}]
    env = make_env("quadruped-flat", num_envs=2, target="slippery_slope", seed=4)
    env.reset()
    dynamics = SimulatorDynamics(env.sims, history=3, obs_dim=89, action_dim=12)
    dynamics.sync()
    history = torch.randn(2, 3, 89 + 12)
    z = dynamics.latent(history)
    assert z.shape == (2, dynamics.latent_dim) and dynamics.history_of(z).shape == (2, 3, 101)
    actions = torch.rand(2, 12) * 2 - 1
    predicted = dynamics.history_of(dynamics(z, actions.double()))
    real = env.step(TensorDict({"action": actions}, [2]))["next", "observation"]
    assert torch.equal(predicted[:, -1], torch.cat([real, actions], -1))
    assert torch.equal(predicted[:, :-1], history[:, 1:])


def test_simulator_planner_keeps_the_window_of_an_encoder_that_reads_previous_actions():
    """The same windows SimDistPolicy builds: [o_t, a_{t-1}], zeros before the first step."""
    from torchrl.envs import InitTracker, TransformedEnv

    from simdist.agents import SimDistAgent
    from simdist.modules import PlannerConfig, SimDistWorldModel
    from simdist.pipelines.simulator_dynamics import SimulatorPlanningPolicy
    agent = SimDistAgent(SimDistWorldModel.build(89, 12, size="tiny", history=2,
                                                 previous_action=True))
    env = TransformedEnv(make_env("quadruped-flat", num_envs=2, seed=0), InitTracker())
    env = env.append_transform(agent.make_primer(0))
    policy = SimulatorPlanningPolicy(agent, env.base_env.sims, PlannerConfig(
        horizon=2, num_samples=4, num_elites=2, iterations=1), -torch.ones(12),
        torch.ones(12), seed=0)
    td = env.rollout(3, policy)
    windows, obs, actions = td["next", "simdist", "history"], td["observation"], td["action"]
    assert windows.shape == (2, 3, 2, 89 + 12)
    previous = torch.cat([torch.zeros_like(actions[:, :1]), actions[:, :-1]], 1)
    assert torch.equal(windows[:, :, -1], torch.cat([obs, previous], -1))
    assert torch.equal(windows[:, 0, 0], windows[:, 0, 1])  # the first step repeated
    assert torch.equal(windows[:, 1:, 0], windows[:, :-1, 1])
    # without the primer's previous action, a clear error
    with pytest.raises(KeyError, match="previous action"):
        policy(TensorDict({"observation": obs[:, 0], "is_init": torch.ones(2, 1, dtype=torch.bool)},
                          [2]))


def test_simulator_planner_scores_by_a_lambda_return_over_the_plans_values():
    """The recipe's default planner reads the value at every 2nd predicted step (a
    [steps, candidates, latent] batch); the simulator planner must take it as the learned
    one does, and its scores must depend on those values (lambda < 1)."""
    from torchrl.envs import InitTracker, TransformedEnv

    from simdist.agents import SimDistAgent
    from simdist.modules import PlannerConfig, SimDistWorldModel
    from simdist.pipelines.simulator_dynamics import SimulatorPlanningPolicy

    def plan(value_lambda):
        torch.manual_seed(0)
        agent = SimDistAgent(SimDistWorldModel.build(89, 12, size="tiny", history=2))
        env = TransformedEnv(make_env("quadruped-flat", num_envs=2, seed=0), InitTracker())
        env = env.append_transform(agent.make_primer(0))
        config = PlannerConfig(horizon=4, num_samples=4, num_elites=2, iterations=1,
                               value_lambda=value_lambda, value_every=2)
        policy = SimulatorPlanningPolicy(agent, env.base_env.sims, config, -torch.ones(12),
                                         torch.ones(12), seed=0)
        return env.rollout(2, policy)

    mixed, terminal = plan(0.95), plan(1.0)
    assert mixed["action"].shape == (2, 2, 12)
    assert torch.isfinite(mixed["planner", "rewards"]).all()
    assert not torch.equal(mixed["action"], terminal["action"])


def test_a_copy_keeps_the_worlds_task_options():
    # a world built with its own incline: a copy built from the speeds alone would be flat
    env = make_env("quadruped-flat", num_envs=1, seed=5, task_kwargs={"slope_deg": 7.0})
    env.reset()
    dynamics = SimulatorDynamics(env.sims, history=2, obs_dim=89)
    dynamics.sync()
    world, copy = env.sims[0], dynamics.copies[0]
    assert copy.task.slope_deg == world.task.slope_deg == 7.0
    floor = world.task._idx["floor"]
    assert (copy.physics.model.geom_quat[floor] == world.physics.model.geom_quat[floor]).all()
    z = dynamics.latent(torch.zeros(1, 2, 89))
    actions = torch.rand(1, 12) * 2 - 1
    predicted = dynamics.history_of(dynamics(z, actions.double()))[:, -1]
    real = env.step(TensorDict({"action": actions}, [1]))["next", "observation"]
    assert torch.equal(predicted, real)
