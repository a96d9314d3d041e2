"""SimDist's perturbed-expert action schedule as a TorchRL policy module.

Per environment and episode: a noise std per joint drawn from ``std_range``; noise is ON
for bursts of ``burst_range`` steps, then OFF for ``pause_range`` steps, repeating; a
``never_noised_fraction`` of episodes is never perturbed. Each episode starts at a random
point of the burst/pause cycle drawn from the cycle's stationary distribution, so the
noised fraction is the schedule's steady state (:meth:`PerturbationSchedule.noised_fraction`)
from the first step on: starting every episode with a full pause would leave most short
episodes unperturbed. The schedule's state lives in
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
    # ``action_low``/``action_high`` bound the perturbed action when the module is given
    # no per-joint bounds (pass the env's action spec to ActionPerturbation instead).
    burst_range: tuple[int, int] = (1, 50)
    pause_range: tuple[int, int] = (25, 500)
    never_noised_fraction: float = 0.025
    # Gaussian noise of this std on every step *outside* the bursts (0: the reference
    # schedule). Bursts (std up to 2.5, clamped) teach what large disturbances do; the
    # planner compares plans that differ by ~0.3 around the prior, and a dynamics model
    # only learns such small action effects where the data varies the action that little.
    dither_std: float = 0.0
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
        if not (math.isfinite(self.dither_std) and self.dither_std >= 0.0):
            raise ValueError(f"dither_std must be finite and >= 0, got {self.dither_std}")
        if not self.action_low < self.action_high:
            raise ValueError("action_low must be < action_high")

    def burst_probability(self) -> float:
        """Long-run fraction of steps inside a burst: ``E[burst] / (E[burst] + E[pause])``.

        Examples:
            >>> round(PerturbationSchedule(burst_range=(1, 3), pause_range=(8, 8)).burst_probability(), 3)
            0.2
        """
        burst, pause = sum(self.burst_range) / 2, sum(self.pause_range) / 2
        return burst / (burst + pause)

    def noised_fraction(self) -> float:
        """Expected fraction of noised steps at any step of an episode (steady state)."""
        return self.burst_probability() * (1.0 - self.never_noised_fraction)


class ActionPerturbation(TensorDictModuleBase):
    """Perturbs ``action`` by the schedule and records ``expert_active``.

    Place it after the expert in a ``TensorDictSequential``; add :meth:`make_primer` and
    ``InitTracker()`` to the env (the schedule restarts where ``is_init`` is set).
    ``expert_active`` is ``True`` where the applied action is the expert's own. The applied
    (and recorded) action is clamped to ``action_low``/``action_high``: pass the env's
    per-joint bounds (``env.action_spec.space.low/high``) so the data holds what the robot
    executed; without them the schedule's scalar bounds apply.

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
                 seed: int = 0, action_key="action", is_init_key="is_init",
                 action_low=None, action_high=None):
        super().__init__()
        self.schedule, self.action_dim = schedule, int(action_dim)
        low = torch.as_tensor(schedule.action_low if action_low is None else action_low,
                              dtype=torch.float32).expand(self.action_dim).clone()
        high = torch.as_tensor(schedule.action_high if action_high is None else action_high,
                               dtype=torch.float32).expand(self.action_dim).clone()
        if not (torch.isfinite(low).all() and torch.isfinite(high).all() and (low < high).all()):
            raise ValueError(f"action bounds must be finite with low < high, got {low}, {high}")
        self.register_buffer("action_low", low)
        self.register_buffer("action_high", high)
        # Stationary start of the cycle: a phase of length l is entered with probability
        # proportional to l (length-biased), then we land uniformly inside it.
        burst = torch.arange(int(schedule.burst_range[0]), int(schedule.burst_range[1]) + 1)
        pause = torch.arange(int(schedule.pause_range[0]), int(schedule.pause_range[1]) + 1)
        self._burst_lengths, self._pause_lengths = burst, pause
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

    def _residual(self, shape, lengths, device):
        """Steps left in a phase entered at a uniformly random time (length-biased)."""
        n = math.prod(shape)
        picked = lengths[torch.multinomial(lengths.float(), n, replacement=True,
                                           generator=self.generator)]
        left = (torch.rand(n, generator=self.generator) * picked).long() + 1  # 1..length
        return left.reshape(shape).to(device)

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
        # Episode start: new per-joint stds, never-noised draw, and a random point of the
        # burst/pause cycle (its stationary distribution: see the module docstring).
        std = torch.where(is_init, self._uniform(std.shape, *s.std_range, dev), std)
        never = torch.where(is_init, self._uniform(flag_shape, 0.0, 1.0, dev)
                            < s.never_noised_fraction, never)
        start_on = self._uniform(flag_shape, 0.0, 1.0, dev) < s.burst_probability()
        start_left = torch.where(start_on, self._residual(flag_shape, self._burst_lengths, dev),
                                 self._residual(flag_shape, self._pause_lengths, dev))
        on = torch.where(is_init, start_on, on)
        remaining = torch.where(is_init, start_left, remaining)
        # Phase change when the current phase is used up.
        flip = remaining <= 0
        on = torch.where(flip, ~on, on)
        fresh = torch.where(on, self._steps(flag_shape, s.burst_range, dev),
                            self._steps(flag_shape, s.pause_range, dev))
        remaining = torch.where(flip, fresh, remaining) - 1
        noisy = on & ~never
        eps = torch.randn(action.shape, generator=self.generator).to(dev)
        low, high = self.action_low.to(dev), self.action_high.to(dev)
        # Dither (if any) rides on every step outside a burst of a perturbed episode; such
        # steps stay ``expert_active``: their BC target is the expert's action plus zero-mean
        # noise, whose regression target is still the expert's mean action.
        dither = s.dither_std * (~never).to(action.dtype)
        applied = torch.where(noisy, action + std * eps, action + dither * eps).clamp(low, high)
        td.set(self.action_key, applied)
        td.set("expert_active", ~noisy)
        for key, value in zip(STATE_KEYS, (std, on, remaining, never)):
            td.set(("next", "perturbation", key), value)
        return td
