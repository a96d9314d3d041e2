"""Agents move to a device as a whole, and their losses and policies stay on it.

This machine has no GPU, so the checks use PyTorch's ``meta`` device: any tensor created
on the CPU inside a loss or policy and mixed with the model's tensors raises ("Tensor on
device cpu is not on the expected device meta"), exactly where it would on CUDA. The
losses' finiteness checks read values back to the host, which a meta tensor cannot, so
they are turned off here (their behaviour is tested elsewhere on the CPU).
"""

import pytest
import torch
from tensordict import TensorDict

from simdist.agents import (DreamerAgent, DreamerConfig, SimDistAgent, TwistConfig,
                            TwistStudent)
from simdist.modules import DreamerWorldModel, SimDistWorldModel
from simdist.objectives.common import SimdistLoss

META = torch.device("meta")


def _agents():
    teacher = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny", horizon=3))
    twist = TwistStudent(teacher, DreamerWorldModel.student(1, "tiny"), TwistConfig(horizon=3))
    simdist = SimDistAgent(SimDistWorldModel.build(10, 3, size="tiny", history=2))
    return teacher, twist, simdist


def _optimisers_and_modules(agent):
    if isinstance(agent, DreamerAgent):
        modules = [agent.world_model, agent.actor, agent.critic, agent.behaviour_loss]
        return [agent.model_optim, agent.actor_optim, agent.critic_optim], modules
    if isinstance(agent, TwistStudent):
        return [agent.optim], [agent.student, agent.teacher.world_model, agent.teacher.actor]
    return [agent.pretrain_optim, agent.finetune_optim, agent.whole_optim], [agent.world_model]


@pytest.mark.parametrize("index", [0, 1, 2], ids=["dreamer", "twist", "simdist"])
def test_to_moves_every_network_and_the_optimisers_still_hold_its_parameters(index):
    agent = _agents()[index]
    optimisers, modules = _optimisers_and_modules(agent)
    before = [[id(p) for group in o.param_groups for p in group["params"]] for o in optimisers]
    assert agent.to("meta") is agent and agent.device == META
    for module in modules:
        assert {t.device for t in (*module.parameters(), *module.buffers())} == {META}
    owned = {id(p) for module in modules for p in module.parameters()}
    for optimiser, ids in zip(optimisers, before):
        now = [id(p) for group in optimiser.param_groups for p in group["params"]]
        # the optimiser trains the module's current parameters (Module.to replaces them
        # on the way to meta), not stale CPU copies
        assert len(now) == len(ids) and set(now) <= owned
        assert all(p.device == META for group in optimiser.param_groups
                   for p in group["params"])


@pytest.fixture
def unchecked(monkeypatch):
    monkeypatch.setattr(SimdistLoss, "finish", staticmethod(lambda td: td))
    teacher, twist, _ = _agents()
    for loss in (teacher.model_loss, twist.distillation, twist.imagined):
        loss.check_inputs = False
    return teacher, twist.to("meta")


def test_dreamer_and_twist_losses_compute_on_the_models_device(unchecked):
    teacher, twist = unchecked
    slices = TensorDict({"action": torch.zeros(2, 6, 1),
                         "is_init": torch.zeros(2, 6, 1, dtype=torch.bool),
                         "next": {"state": torch.zeros(2, 6, 5), "reward": torch.zeros(2, 6, 1),
                                  "pixels": torch.zeros(2, 6, 64, 64, 3, dtype=torch.uint8)}},
                        [2, 6]).to("meta")
    terms = dict(teacher.model_loss(slices.clone()).items())
    batch = slices.clone()
    terms.update(twist.distillation(batch).items())  # writes the posteriors Eq. 4 starts from
    terms.update(twist.imagined(batch).items())
    assert {"loss_reconstruction", "loss_distillation", "loss_imagined"} <= set(terms)
    assert {value.device for value in terms.values()} == {META}


@pytest.mark.parametrize("explore", [False, True])
def test_dreamer_policy_acts_on_the_models_device(unchecked, explore):
    _, twist = unchecked
    for policy, obs in ((twist.teacher.policy(explore=explore), {"state": torch.zeros(3, 5)}),
                        (twist.policy(explore=explore),
                         {"pixels": torch.zeros(3, 64, 64, 3, dtype=torch.uint8)})):
        td = TensorDict({**obs, "is_init": torch.ones(3, 1, dtype=torch.bool)}, [3]).to("meta")
        td = policy(td)
        assert td["action"].shape == (3, 1) and td["action"].device == META
        assert td["next", "agent", "belief"].device == META


def test_policy_hands_back_the_envs_device():
    """A model elsewhere than the env: the action comes back where the observation was."""
    teacher = _agents()[0]
    td = TensorDict({"state": torch.zeros(3, 5), "is_init": torch.ones(3, 1, dtype=torch.bool)},
                    [3])
    out = teacher.policy(explore=False)(td)
    assert out["action"].device == td["state"].device
    assert out["next", "agent", "stoch"].device == td["state"].device


def _sac(frames: int):
    from simdist.agents import AsymmetricSACAgent, AsymmetricSACConfig
    return AsymmetricSACAgent(5, 1, AsymmetricSACConfig(depth=4, hidden=16, frames=frames))


def _sac_slices(steps: int) -> TensorDict:
    return TensorDict({"action": torch.zeros(2, steps, 1),
                       "is_init": torch.zeros(2, steps, 1, dtype=torch.bool),
                       "next": {"state": torch.zeros(2, steps, 5),
                                "reward": torch.ones(2, steps, 1),
                                "terminated": torch.zeros(2, steps, 1, dtype=torch.bool),
                                "pixels": torch.zeros(2, steps, 64, 64, 3, dtype=torch.uint8)}},
                      [2, steps])


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_asymmetric_sac_on_cuda_trains_on_cpu_slices_and_acts_for_a_cpu_env():
    """The recipe's ``--device cuda`` once left the Asymmetric SAC on the CPU: its stage
    never moved the agent, and its update and policy did not move their inputs. (Not on
    ``meta``: ``SACLoss``'s parameter buffers cannot be moved there.)"""
    agent = _sac(3).to("cuda")
    before = [p.detach().clone() for p in agent.loss.actor_network_params.values(True, True)]
    metrics = agent.update(_sac_slices(4))  # the replay keeps its slices on the CPU
    assert all(torch.isfinite(torch.tensor(v)) for v in metrics.values())
    after = list(agent.loss.actor_network_params.values(True, True))
    assert any(not torch.equal(a, b) for a, b in zip(after, before))  # it trained
    assert {t.device.type for t in agent.loss.parameters()} == {"cuda"}
    td = TensorDict({"pixels": torch.zeros(3, 64, 64, 3, dtype=torch.uint8),
                     "is_init": torch.ones(3, 1, dtype=torch.bool),
                     "agent": {"frames": torch.zeros(3, 2, 64, 64, 3, dtype=torch.uint8)}}, [3])
    out = agent.policy(explore=True)(td)
    assert out["action"].device.type == "cpu" and out["action"].shape == (3, 1)
    assert out["next", "agent", "frames"].device.type == "cpu"
