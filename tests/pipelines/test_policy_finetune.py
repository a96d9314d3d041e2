"""The continued-SAC baseline starts exactly at the expert and then moves away from it."""

import torch
from tensordict import TensorDict

from simdist.experts import Expert
from simdist.pipelines import OfflineSAC, OfflineSACConfig


def _data(n=128, obs=6, act=2):
    g = torch.Generator().manual_seed(0)
    return TensorDict({
        "observation": torch.randn(n, obs, generator=g), "action": torch.rand(n, act, generator=g) * 2 - 1,
        "next": {"observation": torch.randn(n, obs, generator=g), "reward": torch.randn(n, 1, generator=g),
                 "done": torch.zeros(n, 1, dtype=torch.bool),
                 "terminated": torch.zeros(n, 1, dtype=torch.bool)}}, [n])


def test_starts_from_the_expert_actor_and_both_critics():
    torch.manual_seed(0)
    expert = Expert.untrained(6, 2, hidden=16)
    sac = OfflineSAC(expert, OfflineSACConfig(batch_size=32))
    obs = TensorDict({"observation": torch.randn(10, 6)}, [10])
    exported = sac.expert()
    torch.testing.assert_close(exported.deterministic()(obs.clone())["action"],
                               expert.deterministic()(obs.clone())["action"])
    q = TensorDict.from_module(expert.critic).data
    for params in (sac.loss.qvalue_network_params, sac.loss.target_qvalue_network_params):
        for i in range(2):
            for key, value in q.items(True, True):
                assert torch.equal(params[i][key], value), key


def test_updates_change_the_policy_and_resume_from_state():
    torch.manual_seed(0)
    expert = Expert.untrained(6, 2, hidden=16)
    sac = OfflineSAC(expert, OfflineSACConfig(batch_size=32))
    buffer = sac.buffer(_data())
    obs = TensorDict({"observation": torch.randn(10, 6)}, [10])
    before = expert.deterministic()(obs.clone())["action"]
    for _ in range(20):
        out = sac.update(buffer.sample())
    assert set(out) == {"loss_actor", "loss_qvalue"}
    after = sac.expert().deterministic()(obs.clone())["action"]
    assert not torch.allclose(before, after)
    copy = OfflineSAC(expert, OfflineSACConfig(batch_size=32))
    copy.load_state_dict(sac.state_dict())
    torch.testing.assert_close(copy.expert().deterministic()(obs.clone())["action"], after)
