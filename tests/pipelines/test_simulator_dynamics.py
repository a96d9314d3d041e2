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


def test_simulator_planner_refuses_an_encoder_that_reads_previous_actions():
    from simdist.agents import SimDistAgent
    from simdist.modules import PlannerConfig, SimDistWorldModel
    from simdist.pipelines.simulator_dynamics import SimulatorPlanningPolicy
    agent = SimDistAgent(SimDistWorldModel.build(10, 3, size="tiny", previous_action=True))
    with pytest.raises(NotImplementedError, match="previous actions"):
        SimulatorPlanningPolicy(agent, worlds=None, planner_config=PlannerConfig(),
                                action_low=None, action_high=None, seed=0)
