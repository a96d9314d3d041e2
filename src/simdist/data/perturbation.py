"""SimDist's perturbed-expert action schedule as a TorchRL policy module.

Per environment and episode: a noise std per joint drawn from ``std_range``; noise is ON
for bursts of ``burst_range`` steps, then OFF for ``pause_range`` steps, repeating; a
``never_noised_fraction`` of episodes is never perturbed. The schedule's state lives in
the TensorDict (``("perturbation", ...)`` keys, written to ``("next", ...)`` and carried
by TorchRL's ``step_mdp`` like an RNN policy's hidden state), so the module itself holds
only its random generator: use one seed per worker (e.g. through a collector's
``policy_factory``) to decorrelate workers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.data import Categorical, Composite, Unbounded
from torchrl.envs import TensorDictPrimer

from simdist.envs.randomisation import check_range

STATE_KEYS = ("std", "noise_on", "remaining", "never")


@dataclass(frozen=True)
class PerturbationSchedule:
    """Ranges of the perturbation schedule (SimDist reference defaults).

    Examples:
        >>> PerturbationSchedule(burst_range=(0, 5))
        Traceback (most recent call last):
        ...
        ValueError: burst_range must be >= 1, got low=0.0
    """

    std_range: tuple[float, float] = (0.05, 2.5)
    burst_range: tuple[int, int] = (1, 50)
    pause_range: tuple[int, int] = (25, 500)
    never_noised_fraction: float = 0.025
    action_low: float = -1.0
    action_high: float = 1.0

    def __post_init__(self):
        check_range("std_range", self.std_range, minimum=0.0)
        check_range("burst_range", self.burst_range, minimum=1)
        check_range("pause_range", self.pause_range, minimum=1)
        for name in ("burst_range", "pause_range"):
            if any(int(v) != v for v in getattr(self, name)):
                raise ValueError(f"{name} must be whole steps, got {getattr(self, name)}")
        if not 0.0 <= self.never_noised_fraction <= 1.0 or math.isnan(self.never_noised_fraction):
            raise ValueError("never_noised_fraction must lie in [0, 1], got "
                             f"{self.never_noised_fraction}")
        if not self.action_low < self.action_high:
            raise ValueError("action_low must be < action_high")


class ActionPerturbation(TensorDictModuleBase):
    """Perturbs ``action`` by the schedule and records ``expert_active``.

    Place it after the expert in a ``TensorDictSequential``; add :meth:`make_primer` and
    ``InitTracker()`` to the env (the schedule restarts where ``is_init`` is set).
    ``expert_active`` is ``True`` where the applied action is the expert's own.

    Examples:
        >>> from tensordict import TensorDict
        >>> perturb = ActionPerturbation(action_dim=2, seed=0)
        >>> td = TensorDict({"action": torch.zeros(4, 2),
        ...                  "is_init": torch.ones(4, 1, dtype=torch.bool)}, [4])
        >>> out = perturb(td)
        >>> out["expert_active"].shape, out["next", "perturbation", "std"].shape
        (torch.Size([4, 1]), torch.Size([4, 2]))
    """

    def __init__(self, action_dim: int, schedule: PerturbationSchedule = PerturbationSchedule(),
                 seed: int = 0, action_key="action", is_init_key="is_init"):
        super().__init__()
        self.schedule, self.action_dim = schedule, int(action_dim)
        self.action_key, self.is_init_key = action_key, is_init_key
        state = [("perturbation", k) for k in STATE_KEYS]
        self.in_keys = [action_key, is_init_key, *state]
        self.out_keys = [action_key, "expert_active", *[("next", *k) for k in state]]
        self.seed = seed
        # Public so a collector hook can reseed it per batch (see simdist.data.dataset).
        self.generator = torch.Generator().manual_seed(seed)

    def make_primer(self) -> TensorDictPrimer:
        """The env transform that creates and resets the schedule's state keys."""
        return TensorDictPrimer(Composite({"perturbation": Composite({
            "std": Unbounded((self.action_dim,)),
            "noise_on": Categorical(2, (1,), dtype=torch.bool),
            "remaining": Unbounded((1,), dtype=torch.int64),
            "never": Categorical(2, (1,), dtype=torch.bool),
        })}), default_value=0, expand_specs=True)

    def _uniform(self, shape, low, high, device):
        return low + (high - low) * torch.rand(shape, generator=self.generator).to(device)

    def _steps(self, shape, bounds, device):
        low, high = int(bounds[0]), int(bounds[1])
        return torch.randint(low, high + 1, shape, generator=self.generator).to(device)

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        s = self.schedule
        action = td.get(self.action_key, None)
        if action is None:
            raise KeyError(f"ActionPerturbation needs {self.action_key!r}: place it after the "
                           "policy that writes it")
        batch, dev = action.shape[:-1], action.device
        flag_shape = (*batch, 1)
        is_init = td.get(self.is_init_key, None)
        if is_init is None:
            raise KeyError(f"ActionPerturbation needs {self.is_init_key!r}: add "
                           "torchrl.envs.InitTracker() to the env")
        is_init = is_init.reshape(flag_shape).bool()

        def state(key, like):
            value = td.get(("perturbation", key), None)
            return like if value is None else value.reshape(like.shape).to(like.dtype)

        std = state("std", torch.zeros(*batch, self.action_dim, device=dev))
        on = state("noise_on", torch.zeros(flag_shape, dtype=torch.bool, device=dev))
        remaining = state("remaining", torch.zeros(flag_shape, dtype=torch.int64, device=dev))
        never = state("never", torch.zeros(flag_shape, dtype=torch.bool, device=dev))
        # Episode start: new per-joint stds, never-noised draw, begin with a pause.
        std = torch.where(is_init, self._uniform(std.shape, *s.std_range, dev), std)
        never = torch.where(is_init, self._uniform(flag_shape, 0.0, 1.0, dev)
                            < s.never_noised_fraction, never)
        on = on & ~is_init
        remaining = torch.where(is_init, self._steps(flag_shape, s.pause_range, dev), remaining)
        # Phase change when the current phase is used up.
        flip = remaining <= 0
        on = torch.where(flip, ~on, on)
        fresh = torch.where(on, self._steps(flag_shape, s.burst_range, dev),
                            self._steps(flag_shape, s.pause_range, dev))
        remaining = torch.where(flip, fresh, remaining) - 1
        noisy = on & ~never
        eps = torch.randn(action.shape, generator=self.generator).to(dev)
        applied = torch.where(noisy, action + std * eps, action).clamp(s.action_low, s.action_high)
        td.set(self.action_key, applied)
        td.set("expert_active", ~noisy)
        for key, value in zip(STATE_KEYS, (std, on, remaining, never)):
            td.set(("next", "perturbation", key), value)
        return td
