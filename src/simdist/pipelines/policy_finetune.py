"""Policy-finetuning baseline: continue the expert's SAC on target-domain data (offline).

SimDist's paper compares finetuning the world model's dynamics against finetuning a
policy on the same real data (IQL, RLPD). This baseline starts TorchRL's ``SACLoss`` from
the expert's actor **and** critic (both Q copies and their targets get the expert
critic's weights: ``SACLoss`` would otherwise re-draw the second copy) and trains on the
fixed target dataset, with a fixed small entropy temperature since the expert's own
temperature is not part of its deployable checkpoint.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import torch
from tensordict import TensorDict
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.objectives import SACLoss, SoftUpdate

from simdist.experts import Expert

SAC_KEYS = ["observation", "action", ("next", "observation"), ("next", "reward"),
            ("next", "done"), ("next", "terminated")]


@dataclass
class OfflineSACConfig:
    """Continued-SAC settings (the expert's own lr, gamma and tau).

    Examples:
        >>> sac = OfflineSAC(Expert.untrained(obs_dim=4, action_dim=2, hidden=8),
        ...                  OfflineSACConfig(lr=1e-4, alpha=0.05))
        >>> sac.optim.param_groups[0]["lr"], sac.loss.log_alpha.requires_grad  # alpha stays fixed
        (0.0001, False)
    """

    updates: int = 1000
    batch_size: int = 256
    lr: float = 3e-4
    gamma: float = 0.99
    tau: float = 0.005
    alpha: float = 0.01
    seed: int = 0


class OfflineSAC:
    """Continues SAC from an :class:`~simdist.experts.Expert` on a fixed dataset.

    Examples:
        >>> expert = Expert.untrained(obs_dim=4, action_dim=2, hidden=8)
        >>> data = TensorDict({"observation": torch.randn(64, 4), "action": torch.rand(64, 2),
        ...     "next": {"observation": torch.randn(64, 4), "reward": torch.randn(64, 1),
        ...              "done": torch.zeros(64, 1, dtype=torch.bool),
        ...              "terminated": torch.zeros(64, 1, dtype=torch.bool)}}, [64])
        >>> sac = OfflineSAC(expert, OfflineSACConfig(batch_size=16))
        >>> sorted(sac.update(data[:16]))
        ['loss_actor', 'loss_qvalue']
    """

    def __init__(self, expert: Expert, config: OfflineSACConfig = OfflineSACConfig()):
        self.config = config
        actor, critic = copy.deepcopy(expert.actor), copy.deepcopy(expert.critic)
        # SACLoss keeps functional parameters; these plain copies receive them on export.
        self._templates = copy.deepcopy(expert.actor), copy.deepcopy(expert.critic)
        self.loss = SACLoss(actor, critic, num_qvalue_nets=2, loss_function="l2",
                            alpha_init=config.alpha, fixed_alpha=True)
        self.updater = SoftUpdate(self.loss, tau=config.tau)  # before any target access
        self.loss.make_value_estimator(gamma=config.gamma)
        expert_q = TensorDict.from_module(expert.critic).data
        for params in (self.loss.qvalue_network_params, self.loss.target_qvalue_network_params):
            for i in range(params.shape[0]):
                params.data[i].update_(expert_q)
        self.optim = torch.optim.Adam(self.loss.parameters(), lr=config.lr)

    def update(self, batch: TensorDict) -> dict[str, float]:
        out = self.loss(batch)
        total = out["loss_actor"] + out["loss_qvalue"]
        self.optim.zero_grad(set_to_none=True)
        total.backward()
        self.optim.step()
        self.updater.step()
        return {"loss_actor": out["loss_actor"].item(), "loss_qvalue": out["loss_qvalue"].item()}

    def buffer(self, data: TensorDict) -> TensorDictReplayBuffer:
        """A replay buffer over ``data`` (any batch shape) holding the SAC keys."""
        flat = data.select(*SAC_KEYS).reshape(-1)
        buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(flat.numel()),
                                        batch_size=self.config.batch_size)
        buffer.extend(flat)
        return buffer

    def expert(self) -> Expert:
        """The finetuned policy (and first Q copy) as an :class:`Expert`."""
        actor, critic = (copy.deepcopy(m) for m in self._templates)
        TensorDict.from_module(actor).data.update_(self.loss.actor_network_params.data)
        TensorDict.from_module(critic).data.update_(self.loss.qvalue_network_params.data[0])
        return Expert(actor.eval(), critic.eval())

    def state_dict(self) -> dict:
        return {"loss": self.loss.state_dict(), "optim": self.optim.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.loss.load_state_dict(state["loss"])
        self.optim.load_state_dict(state["optim"])
