"""The latent MPPI/CEM planner's hyperparameters (:class:`PlannerConfig`)."""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass

from simdist.utils.precision import PRECISIONS


@dataclass(frozen=True)
class PlannerConfig:
    """MPPI/CEM hyperparameters (defaults: a CPU-friendly configuration).

    ``PlannerConfig.reference()`` gives the SimDist reference values: horizon 25, 450
    samples, 8 iterations, 64 elites, temperature 0.25, discount 0.99, std 2.0 -> 0.05,
    5% policy proposals with noise 0.05.

    Examples:
        >>> PlannerConfig.reference().num_samples
        450
        >>> PlannerConfig(num_samples=8, num_elites=16)
        Traceback (most recent call last):
        ...
        ValueError: num_elites (16) must be <= num_samples (8)
    """

    horizon: int = 5
    num_samples: int = 64
    iterations: int = 3
    num_elites: int = 8
    temperature: float = 0.25
    gamma: float = 0.99
    init_std: float = 2.0
    min_std: float = 0.05
    max_std: float = 2.0
    policy_fraction: float = 0.05
    policy_noise: float = 0.05
    action_low: float = -1.0
    action_high: float = 1.0
    warm_start: bool = True
    # Control steps of action delay the policy compensates (SimDist reference: 1): before
    # planning, the latent is rolled forward through the last k actions already sent to
    # the robot, so the plan starts where its first action will be applied. Used by
    # SimDistPolicy; the env needs SimDistAgent.make_primer(latency_compensation=k).
    latency_compensation: int = 0
    # Weight of the terminal value gamma^H V(z_H) in a candidate's score (the reference:
    # 1). 0 ranks candidates by their predicted rewards alone.
    value_weight: float = 1.0
    # Mixes the value bootstrap over the horizon (a lambda-return, as TorchRL's MPPIPlanner
    # scores with TDLambdaEstimator and Dreamer's critic learns): G_H = V(z_H), G_t = r_t +
    # gamma ((1 - lambda) V(z_t+1) + lambda G_t+1), each V times value_weight. 1: the
    # terminal value alone (the reference). Below 1 the score leans on values read after
    # fewer predicted steps, whose latents carry less compounded model error; it costs a
    # value-head call per predicted step instead of one at the end (intermediate values at
    # the rollout's precision, see _rollout).
    value_lambda: float = 1.0
    # Reads the lambda-return's values at every k-th predicted latent only (1: at each),
    # mixing with lambda^k there, so each value carries the weight the every-step return
    # spreads over the k latents up to it (the terminal value: over those after the last
    # one read): the same geometric weighting in H / k value calls instead of H. Unused
    # when lambda is 1.
    value_every: int = 1
    # Temporal colour of the sampling noise along the horizon (iCEM, Pinneri et al. 2020):
    # its power spectrum falls as 1/f^noise_beta. 0: white noise, every step drawn on its
    # own (the reference); 2: smooth, low-frequency sequences; large: nearly one offset
    # held for the whole horizon. Each step's marginal stays N(0, 1) whatever the colour.
    noise_beta: float = 0.0
    # Steps at the start of the horizon on which the policy prior's proposals carry noise
    # (0: every step). 1 makes the proposals differ only in the action executed now and
    # follow the prior afterwards, so each proposal's score is the model's estimate of
    # that first action under the prior, undiluted by noise on steps that are re-planned.
    policy_noise_steps: int = 0
    # Commands the policy prior is also asked about (command-diverse proposals; empty: off).
    # The prior is one gait per command, learnt where the robot was trained; under a
    # shifted dynamics another command's gait can track this command better (a slow gait
    # that slides back on ice while a faster one climbs). With commands given, SimDistPolicy
    # encodes the history once more per command (the observation's command entry
    # replaced) and the planner splits its prior proposals evenly between the episode's own
    # latent and these: each such proposal rolls the prior from its command's latent to
    # make an action sequence, then is scored from the true latent, so the rewards and
    # value are always the episode's own command's. Costs one more rollout per such
    # proposal.
    proposal_commands: tuple[float, ...] = ()
    # Arithmetic of the candidates' rollouts: "none" (float32) or "bfloat16" (the models
    # run under torch.autocast: matmuls in bfloat16 but the terminal value head's, scores
    # accumulated and the MPPI update in float32). On CPU cores with AVX512-BF16 a call costs 2.6x less; on an H200
    # only large sample counts gain; on AVX2-only cores it costs several times more
    # (docs/findings.md). "auto": bfloat16 where the device has native bfloat16
    # matmuls, else float32 (simdist.utils.precision). Outputs stay float32.
    precision: str = "none"

    def __post_init__(self):
        for name in ("horizon", "num_samples", "iterations", "num_elites",
                     "latency_compensation", "policy_noise_steps", "value_every"):
            value = getattr(self, name)
            # bool is an int, and 2.5 would be truncated silently by the tensor shapes.
            if isinstance(value, bool) or not isinstance(value, numbers.Integral):
                raise ValueError(f"{name} must be an integer, got {value!r}")
            least = 0 if name in ("latency_compensation", "policy_noise_steps") else 1
            if value < least:
                raise ValueError(f"{name} must be >= {least}, got {value}")
        for name in ("temperature", "gamma", "init_std", "min_std", "max_std",
                     "policy_fraction", "policy_noise", "action_low", "action_high",
                     "value_weight", "noise_beta", "value_lambda"):
            value = getattr(self, name)
            # NaN passes every "< 0" style check below, so test finiteness first.
            if not (isinstance(value, numbers.Real) and math.isfinite(value)):
                raise ValueError(f"{name} must be a finite number, got {value!r}")
        if self.num_elites > self.num_samples:
            raise ValueError(f"num_elites ({self.num_elites}) must be <= num_samples "
                             f"({self.num_samples})")
        if not (self.temperature > 0 and math.isfinite(self.temperature)):
            raise ValueError(f"temperature must be finite and > 0, got {self.temperature}")
        if not 0 < self.gamma <= 1:
            raise ValueError(f"gamma must lie in (0, 1], got {self.gamma}")
        if not 0 < self.min_std <= self.init_std <= self.max_std:
            raise ValueError("stds must satisfy 0 < min_std <= init_std <= max_std, got "
                             f"{self.min_std}, {self.init_std}, {self.max_std}")
        if not 0 <= self.policy_fraction < 1 or self.policy_noise < 0:
            raise ValueError("policy_fraction must lie in [0, 1) and policy_noise >= 0")
        if not self.action_low < self.action_high:
            raise ValueError(f"action bounds inverted: {self.action_low} >= {self.action_high}")
        if self.value_weight < 0:
            raise ValueError(f"value_weight must be >= 0, got {self.value_weight}")
        if self.noise_beta < 0:
            raise ValueError(f"noise_beta must be >= 0, got {self.noise_beta}")
        if not 0 <= self.value_lambda <= 1:
            raise ValueError(f"value_lambda must lie in [0, 1], got {self.value_lambda}")
        commands = tuple(self.proposal_commands)
        if not all(isinstance(v, numbers.Real) and math.isfinite(v) for v in commands):
            raise ValueError(f"proposal_commands must be finite numbers, got {commands!r}")
        # a list read back from a checkpoint's JSON becomes the tuple a frozen config holds
        object.__setattr__(self, "proposal_commands", tuple(float(v) for v in commands))
        if self.precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {list(PRECISIONS)}, got "
                             f"{self.precision!r}")

    @classmethod
    def reference(cls, **overrides) -> PlannerConfig:
        """The SimDist reference configuration (a GPU-scale planner)."""
        base = cls(horizon=25, num_samples=450, iterations=8, num_elites=64)
        return dataclasses.replace(base, **overrides)

    @property
    def num_policy(self) -> int:
        return int(round(self.policy_fraction * self.num_samples))
