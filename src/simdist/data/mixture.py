"""Per-episode choice among several policies (final expert vs. earlier checkpoints)."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.data import Composite, Unbounded
from torchrl.envs import TensorDictPrimer


class EpisodeMixture(TensorDictModuleBase):
    """At each episode start, picks policy ``k`` with ``probabilities[k]`` for that env.

    All policies run on the batch and each env takes its episode's policy's action, so
    there is no per-env Python loop. The chosen index is carried in the TensorDict as
    ``("mixture", "policy")`` (add :meth:`make_primer` and ``InitTracker()`` to the env)
    and recorded per step.

    Examples:
        >>> from tensordict import TensorDict
        >>> const = lambda v: (lambda td: td.set("action", torch.full((td.shape[0], 1), v)))
        >>> mix = EpisodeMixture([const(1.0), const(-1.0)], [0.5, 0.5], seed=0)
        >>> td = TensorDict({"is_init": torch.ones(1000, 1, dtype=torch.bool)}, [1000])
        >>> abs(mix(td)["action"].mean().item()) < 0.1
        True
    """

    def __init__(self, policies, probabilities, seed: int = 0, action_key="action",
                 is_init_key="is_init"):
        super().__init__()
        probs = torch.as_tensor(probabilities, dtype=torch.float64)
        if len(policies) != len(probs) or len(probs) == 0:
            raise ValueError("need one probability per policy")
        if (probs < 0).any() or abs(probs.sum().item() - 1.0) > 1e-6:
            raise ValueError(f"probabilities must be >= 0 and sum to 1, got {probabilities}")
        self.policies = list(policies)
        self._modules_held = torch.nn.ModuleList(p for p in policies
                                                 if isinstance(p, torch.nn.Module))
        self.register_buffer("probabilities", probs.float())
        self.action_key, self.is_init_key = action_key, is_init_key
        self.in_keys = [is_init_key, ("mixture", "policy")]
        self.out_keys = [action_key, ("next", "mixture", "policy")]
        # Public so a collector hook can reseed it per batch (see simdist.data.dataset).
        self.generator = torch.Generator().manual_seed(seed)

    def make_primer(self) -> TensorDictPrimer:
        return TensorDictPrimer(Composite({"mixture": Composite({
            "policy": Unbounded((1,), dtype=torch.int64)})}), default_value=0, expand_specs=True)

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        is_init = td.get(self.is_init_key, None)
        if is_init is None:
            raise KeyError("EpisodeMixture needs 'is_init': add torchrl.envs.InitTracker()")
        shape = is_init.shape
        current = td.get(("mixture", "policy"), None)
        current = torch.zeros(shape, dtype=torch.int64) if current is None else current
        draw = torch.multinomial(self.probabilities, shape.numel(), replacement=True,
                                 generator=self.generator).reshape(shape)
        choice = torch.where(is_init.bool(), draw.to(current.device), current)
        # Each policy sees only the keys it reads (when it declares them): cheaper than a
        # shallow clone of the whole step, which carries every observation and state key.
        actions = torch.stack([p(self._inputs(td, p)).get(self.action_key)
                               for p in self.policies])
        index = choice.reshape(1, *choice.shape[:-1], 1).expand(1, *actions.shape[1:])
        td.set(self.action_key, actions.gather(0, index)[0])
        td.set(("next", "mixture", "policy"), choice)
        return td

    @staticmethod
    def _inputs(td: TensorDictBase, policy) -> TensorDictBase:
        keys = getattr(policy, "in_keys", None)
        return td.select(*keys, strict=False) if keys else td.clone(False)
