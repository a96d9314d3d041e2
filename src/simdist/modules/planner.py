"""Latent MPPI/CEM planner (SimDist reference algorithm, docs/methods.md Sec. 1.4).

Differences from TorchRL 0.14's ``MPPIPlanner``, each measured or tested: the sampling
distribution is warm-started from the previous plan shifted by one step (reset per env
on ``is_init``); a fraction of candidates is proposed by a policy prior plus noise;
trajectories are scored with discounted rewards plus ``gamma^H V(z_H)``; elite scores are
normalised before the exponential, so equal or non-finite scores never produce NaN; and
the loop runs on tensors (no per-step TensorDicts, no host syncs), optionally compiled.
"""

from __future__ import annotations


import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictModuleBase
from torch import nn

from simdist.modules.planner_config import PlannerConfig
from simdist.utils.precision import autocast_dtype

__all__ = ["PlannerConfig", "LatentMPPIPlanner", "colored_noise"]


def colored_noise(white: torch.Tensor, beta: float, dim: int = -2) -> torch.Tensor:
    """Gives standard-normal ``white`` noise a ``1/f^beta`` power spectrum along ``dim``.

    The white samples are filtered in the frequency domain (amplitude ``f^(-beta/2)``, the
    zero frequency treated as the lowest one, ``1/n``, as in iCEM's colored noise) and
    rescaled so that every step keeps unit variance: the noise is as large as before, only
    correlated in time. ``beta = 0`` returns ``white`` unchanged.

    Examples:
        >>> g = torch.Generator().manual_seed(0)
        >>> x = colored_noise(torch.randn(4096, 20, 1, generator=g), beta=2.0)
        >>> round(float(x.std()), 1), x.shape
        (1.0, torch.Size([4096, 20, 1]))
        >>> lag1 = (x[:, 1:] * x[:, :-1]).mean()
        >>> bool(lag1 > 0.5)  # neighbouring steps now move together
        True
    """
    if beta == 0:
        return white
    n = white.shape[dim]
    # |f| over the full (two-sided) spectrum, in units of the lowest frequency 1/n, so the
    # amplitudes are <= 1 and a large beta cannot overflow.
    freqs = torch.fft.fftfreq(n, device=white.device, dtype=white.dtype).abs() * n
    amplitude = freqs.clamp_min(1.0).pow(-beta / 2)
    # Each output step's variance is the mean squared amplitude over the full spectrum.
    amplitude = amplitude / amplitude.pow(2).mean().sqrt()
    shape = [1] * white.dim()
    shape[dim] = n // 2 + 1  # rfft keeps the non-negative half
    spectrum = torch.fft.rfft(white, dim=dim) * amplitude[: n // 2 + 1].reshape(shape)
    return torch.fft.irfft(spectrum, n=n, dim=dim)


def _as_function(module):
    """Tensor-level callable from a module: TensorDictModules are called on their tensors."""
    if isinstance(module, TensorDictModule):
        return module.module
    if isinstance(module, TensorDictModuleBase):
        raise TypeError("pass a TensorDictModule wrapping a tensor module (or the module "
                        "itself): the planner calls it on tensors inside its loop")
    return module


class LatentMPPIPlanner(TensorDictModuleBase):
    """Sampling-based MPC in a learned latent space, as a ``TensorDictModule``.

    Reads ``latent_key`` (``[B, L]``: B environments at once) and, if present,
    ``is_init_key`` (``[B, 1]``; resets that env's warm start). Writes ``action_key``
    (``[B, A]``) and, for inspection, ``("planner", "mean")`` (``[B, H, A]``, the final plan),
    ``("planner", "std")``, ``("planner", "rewards")`` (``[B, H]``) and
    ``("planner", "value")`` (``[B]``): predicted rewards and terminal value along the best
    trajectory of the last iteration, and ``("planner", "elite_actions")``
    (``[B, K, H, A]``, best first). With ``proposal_latent_key`` (``[B, C, L]``, e.g. the
    same history encoded under other commands: ``PlannerConfig.proposal_commands``) the
    prior's proposals are shared between ``latent`` and those C latents; all are scored
    from ``latent``.

    Args:
        dynamics: ``(z [N, L], a [N, A]) -> z' [N, L]``.
        reward: ``(z, a) -> r [N, 1]``.
        value: ``z -> V [N, 1]`` (terminal value), or ``None`` for zero.
        action_dim: action size.
        config: :class:`PlannerConfig`.
        policy: ``z -> a`` proposal prior, or ``None`` (no proposals).
        seed: seeds the sampling noise (deterministic plans).
        compile: ``torch.compile`` the planning loop (``mode="reduce-overhead"`` on CUDA
            uses CUDA graphs). Eager by default.
        action_bounds: per-dimension ``(low, high)`` tensors (e.g. an env's action spec),
            overriding the config's scalar bounds.
        latent_dim: the latent size ``L`` the models expect, checked on every call
            (default: ``dynamics.latent_dim`` if it has one; ``from_world_model`` sets it).
        proposal_latent_key: where other latents to roll the prior from are read, if
            present.

    Inputs are checked at the boundary, naming the key: ``latent`` must be a finite
    floating-point ``[B, L]`` (a NaN or inf latent would otherwise give a finite,
    meaningless action) and ``is_init`` must hold one flag per environment. The checks
    cost one ``isfinite().all()`` per call and run outside the compiled loop.

    Examples:
        >>> from tensordict import TensorDict
        >>> planner = LatentMPPIPlanner(
        ...     dynamics=lambda z, a: z + 0.1 * a, reward=lambda z, a: -(z - 1.0).pow(2),
        ...     value=None, action_dim=1, config=PlannerConfig(horizon=5, num_samples=64,
        ...     num_elites=8, iterations=4), seed=0)
        >>> td = planner(TensorDict({"latent": torch.zeros(2, 1)}, [2]))
        >>> bool((td["action"] > 0.5).all())  # head towards z = 1 at full speed
        True
    """

    def __init__(self, dynamics, reward, value, action_dim: int,
                 config: PlannerConfig = PlannerConfig(), policy=None, seed: int = 0,
                 compile: bool = False, latent_key="latent", action_key="action",
                 is_init_key="is_init", action_bounds=None, latent_dim: int | None = None,
                 proposal_latent_key="proposal_latent"):
        super().__init__()
        self.config, self.action_dim = config, int(action_dim)
        latent_dim = latent_dim if latent_dim is not None else getattr(
            _as_function(dynamics), "latent_dim", None)
        self.latent_dim = int(latent_dim) if latent_dim is not None else None
        self.latent_key, self.action_key, self.is_init_key = latent_key, action_key, is_init_key
        self.proposal_latent_key = proposal_latent_key
        self.in_keys = [latent_key, is_init_key, proposal_latent_key]
        self.out_keys = [action_key, ("planner", "mean"), ("planner", "std"),
                         ("planner", "rewards"), ("planner", "value"),
                         ("planner", "elite_actions")]
        # Keep modules registered (device moves, state dicts) but call them as tensors.
        self._modules_held = nn.ModuleList(m for m in (dynamics, reward, value, policy)
                                           if isinstance(m, nn.Module))
        self._dynamics, self._reward = _as_function(dynamics), _as_function(reward)
        self._value = _as_function(value) if value is not None else None
        self._policy = _as_function(policy) if policy is not None else None
        low, high = action_bounds if action_bounds is not None else (
            torch.full((self.action_dim,), config.action_low),
            torch.full((self.action_dim,), config.action_high))
        low, high = torch.as_tensor(low, dtype=torch.float32), torch.as_tensor(high, dtype=torch.float32)
        if low.shape != (self.action_dim,) or high.shape != (self.action_dim,) or (low >= high).any():
            raise ValueError(f"action_bounds must be two ({self.action_dim},) tensors with "
                             f"low < high, got {low} and {high}")
        # Buffers start where the models are: a planner built from a CUDA model plans on CUDA
        # without a later .to(device) (the bounds would otherwise stay on the CPU).
        device = next((p.device for p in self._modules_held.parameters()), low.device)
        self.register_buffer("action_low", low.to(device))
        self.register_buffer("action_high", high.to(device))
        self.generator_seed = seed
        self._generator = None
        self.register_buffer("_previous_mean", torch.zeros(0, device=device), persistent=False)
        self._plan_impl = torch.compile(self._plan, mode=(
            "reduce-overhead" if torch.cuda.is_available() else "default")) if compile \
            else self._plan

    @classmethod
    def from_world_model(cls, world_model, config: PlannerConfig = PlannerConfig(),
                         use_policy: bool = True, **kwargs) -> LatentMPPIPlanner:
        """A planner over a :class:`~simdist.modules.SimDistWorldModel`'s verbs."""
        kwargs.setdefault("latent_dim", world_model.latent_dim)
        return cls(world_model.dynamics, world_model.reward_head, world_model.value_head,
                   world_model.action_dim, config,
                   policy=world_model.policy_head if use_policy else None, **kwargs)

    # -- state ----------------------------------------------------------------------------
    def reset(self) -> None:
        """Forgets every warm start (e.g. before a new batch of episodes)."""
        self._previous_mean = torch.zeros(0, device=self._previous_mean.device)

    def _noise_generator(self, device) -> torch.Generator:
        if self._generator is None or self._generator.device != torch.device(device):
            self._generator = torch.Generator(device=device).manual_seed(self.generator_seed)
        return self._generator

    def _initial_mean(self, latent: torch.Tensor, is_init) -> torch.Tensor:
        B, H, A = latent.shape[0], self.config.horizon, self.action_dim
        zeros = torch.zeros(B, H, A, device=latent.device, dtype=latent.dtype)
        prev = self._previous_mean
        if not self.config.warm_start or prev.shape != zeros.shape:
            return zeros
        shifted = torch.cat([prev[:, 1:], torch.zeros_like(prev[:, :1])], 1)
        if is_init is not None:
            shifted = torch.where(is_init.reshape(B, 1, 1).bool(), zeros, shifted)
        return shifted

    # -- the algorithm --------------------------------------------------------------------
    def _rollout(self, latent: torch.Tensor, n: int, action_at):
        """Rolls ``n`` candidates per env from ``latent [B, L]`` for ``H`` steps, the action
        of step ``t`` given by ``action_at(t, z_t)`` (``[B * n, A]``), scoring as it goes.

        Returns the actions ``[B, n, H, A]``, discounted returns ``[B, n]`` (rewards of
        ``(z_t, a_t)`` plus the weighted terminal value), rewards ``[B, n, H]`` and terminal
        values ``[B, n]``.
        """
        c, B, H = self.config, latent.shape[0], self.config.horizon
        z = latent[:, None].expand(B, n, latent.shape[-1]).reshape(B * n, -1)
        total = torch.zeros(B * n, device=latent.device, dtype=latent.dtype)
        actions, rewards, latents = [], [], []
        mixed = self._value is not None and c.value_lambda < 1
        # steps t whose next latent z_t+1 (every k-th, before z_H) is valued along the plan
        read = range(c.value_every - 1, H - 1, c.value_every) if mixed else range(0)
        values = {}
        for t in range(H):
            a = action_at(t, z)
            actions.append(a)
            r = self._reward(z, a).reshape(B * n)
            rewards.append(r)
            total = total + (c.gamma ** t) * r
            z = self._dynamics(z, a)
            if t in read:
                latents.append(z)
        if self._value is not None:
            # The terminal value (~80 on the quadruped) decides most of the ranking, and
            # bfloat16 rounds it in steps of 0.5, as wide as its spread over a state's
            # candidates: under autocast the value head alone runs in float32 (one call per
            # candidate against H of the dynamics and reward head).
            with torch.autocast(z.device.type, enabled=False):
                value = self._value(z.float()).reshape(B * n).to(total.dtype)
            if read:
                # The values along the plan in one call at the rollout's precision: each
                # weighs (1 - lambda^k) gamma^t, so bfloat16's rounding matters far less
                # than on the terminal value, and a float32 call per step would double the
                # planner's time.
                along = self._value(torch.stack(latents)).reshape(len(read), B * n)
                values = dict(zip(read, along.to(total.dtype)))
        else:
            value = torch.zeros_like(total)
        if mixed:  # the lambda-return, backwards from G_H = V(z_H)
            lam, w = c.value_lambda ** c.value_every, c.value_weight
            total = w * value  # G_H; values[t] is V(z_t+1)
            for t in reversed(range(H)):
                if t in values:
                    total = rewards[t] + c.gamma * ((1 - lam) * w * values[t] + lam * total)
                else:  # no value read at z_t+1 (the terminal one, or between every k-th)
                    total = rewards[t] + c.gamma * total
        else:
            total = total + c.value_weight * (c.gamma ** H) * value
        return (torch.stack(actions, 1).reshape(B, n, H, -1), total.reshape(B, n),
                torch.stack(rewards, -1).reshape(B, n, H), value.reshape(B, n))

    def _evaluate(self, latent: torch.Tensor, actions: torch.Tensor):
        """Discounted return, rewards and terminal value of ``actions [B, N, H, A]``."""
        B, N, H, _ = actions.shape
        flat = actions.reshape(B * N, H, -1)
        return self._rollout(latent, N, lambda t, z: flat[:, t])[1:]

    def _policy_proposals(self, latent: torch.Tensor, noise: torch.Tensor):
        """Rolls the policy prior (+ noise) from ``latent`` and scores the result on the way.

        Returns the proposals ``[B, P, H, A]`` with the same returns, rewards and values
        :meth:`_evaluate` would give them, so they are never rolled through the dynamics a
        second time.
        """
        return self._rollout(latent, noise.shape[1],
                             lambda t, z: self._prior_action(z, noise[:, :, t]))

    def _prior_action(self, z: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
        """The prior's action at ``z [B * P, L]`` plus ``noise [B, P, A]``, in bounds."""
        noisy = self._policy(z) + self.config.policy_noise * noise.reshape(z.shape[0], -1)
        return noisy.clamp(self.action_low, self.action_high)

    def _prior_actions(self, starts: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
        """Action sequences ``[B, P, H, A]`` of the prior (+ noise) rolled from ``starts
        [B, P, L]`` through the dynamics (no scoring: other latents' rewards are not the
        episode's)."""
        (B, P), H = noise.shape[:2], self.config.horizon
        z, actions = starts.reshape(B * P, -1), []
        for t in range(H):
            a = self._prior_action(z, noise[:, :, t])
            actions.append(a)
            if t + 1 < H:
                z = self._dynamics(z, a)
        return torch.stack(actions, 1).reshape(B, P, H, -1)

    def _proposals(self, latent, noise, proposal_latent):
        """Prior proposals from the episode's own latent and, with ``proposal_latent [B, C,
        L]``, from each of those (every ``C + 1``-th proposal from the same latent), all
        scored from ``latent``."""
        if proposal_latent is None:
            return self._policy_proposals(latent, noise)
        group = torch.arange(noise.shape[1], device=noise.device) % (proposal_latent.shape[1] + 1)
        own = self._policy_proposals(latent, noise[:, group == 0])
        starts = proposal_latent[:, group[group > 0] - 1]
        actions = self._prior_actions(starts, noise[:, group > 0])
        other = (actions, *self._evaluate(latent, actions))
        return tuple(torch.cat(x, 1) for x in zip(own, other))

    def _plan(self, latent, mean, sample_noise, policy_noise, proposal_latent=None):
        c = self.config
        B, K = latent.shape[0], c.num_elites
        std = torch.full_like(mean, c.init_std)
        # The proposals do not change across iterations (same latent, same actions), so
        # they are rolled out and scored once; each iteration scores only its new random
        # samples (with 90% proposals, ~2.2x less model work than rescoring all).
        proposals = (self._proposals(latent, policy_noise, proposal_latent)
                     if policy_noise is not None else None)
        for i in range(c.iterations):
            parts = []
            if sample_noise.shape[2]:
                actions = (mean[:, None] + std[:, None] * sample_noise[i]).clamp(
                    self.action_low, self.action_high)
                parts.append((actions, *self._evaluate(latent, actions)))
            if proposals is not None:
                parts.insert(0, proposals)
            actions, scores, rewards, values = (torch.cat(x, 1) for x in zip(*parts))
            # Non-finite scores (a diverging model) rank last instead of poisoning the update.
            scores = torch.nan_to_num(scores, nan=-1e30, posinf=1e30, neginf=-1e30)
            elite_scores, index = scores.topk(K, dim=1)
            elites = actions.gather(1, index[..., None, None].expand(B, K, *actions.shape[2:]))
            # Normalise by the elite spread so the temperature is scale-free; equal scores
            # give uniform weights, never NaN.
            spread = (elite_scores[:, :1] - elite_scores[:, -1:]).clamp_min(1e-6)
            weights = torch.softmax((elite_scores - elite_scores[:, :1]) / (spread * c.temperature), 1)
            w = weights[..., None, None]
            # A convex combination stays in bounds up to rounding: clamp to make it exact.
            mean = (w * elites).sum(1).clamp(self.action_low, self.action_high)
            std = ((w * (elites - mean[:, None]).pow(2)).sum(1)).sqrt().clamp(c.min_std, c.max_std)
        # Predictions along the best elite of the last iteration (no extra model pass).
        best = index[:, 0]
        batch = torch.arange(B, device=latent.device)
        return mean, std, rewards[batch, best], values[batch, best], elites

    def _proposal_latent(self, tensordict, latent, squeeze: bool) -> torch.Tensor | None:
        """``proposal_latent_key`` (``[B, C, L]``) checked against ``latent [B, L]``, or
        ``None`` without it, without a prior or without prior proposals."""
        other = tensordict.get(self.proposal_latent_key, None)
        if other is None or self._policy is None or not self.config.num_policy:
            return None
        other = other[None] if squeeze else other
        if other.dim() != 3 or other.shape[0] != latent.shape[0] or \
                other.shape[-1] != latent.shape[-1]:
            raise ValueError(f"{self.proposal_latent_key!r} must be [B, C, L] with B, L as "
                             f"{self.latent_key!r} {tuple(latent.shape)}, got "
                             f"{tuple(other.shape)}")
        if not torch.isfinite(other).all():
            raise ValueError(f"{self.proposal_latent_key!r} contains NaN or inf")
        return other.to(latent.dtype)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        latent = tensordict.get(self.latent_key, None)
        if latent is None:
            raise KeyError(f"LatentMPPIPlanner: input has no {self.latent_key!r}; present: "
                           f"{sorted(map(str, tensordict.keys(True, True)))}")
        squeeze = latent.dim() == 1
        latent = latent[None] if squeeze else latent
        if latent.dim() != 2:
            raise ValueError(f"{self.latent_key!r} must be [B, L] (or [L]), got "
                             f"{tuple(latent.shape)}")
        if self.latent_dim is not None and latent.shape[-1] != self.latent_dim:
            raise ValueError(f"{self.latent_key!r} has size {latent.shape[-1]}, the models "
                             f"expect {self.latent_dim} (shape {tuple(latent.shape)})")
        if not latent.is_floating_point():
            raise TypeError(f"{self.latent_key!r} must be floating point, got {latent.dtype}")
        # One check (a host sync on CUDA) per call: a NaN/inf latent would otherwise be
        # planned from silently, giving a finite but meaningless action.
        if not torch.isfinite(latent).all():
            raise ValueError(f"{self.latent_key!r} contains NaN or inf (is the encoder's "
                             "input finite?); refusing to plan from it")
        is_init = tensordict.get(self.is_init_key, None)
        c, B = self.config, latent.shape[0]
        if is_init is not None and is_init.numel() != B:
            raise ValueError(f"{self.is_init_key!r} must hold one flag per environment "
                             f"({B}, as {self.latent_key!r} {tuple(latent.shape)}), got "
                             f"shape {tuple(is_init.shape)}")
        proposal_latent = self._proposal_latent(tensordict, latent, squeeze)
        gen = self._noise_generator(latent.device)
        with torch.no_grad():
            mean = self._initial_mean(latent, is_init)
            n_random = c.num_samples - (c.num_policy if self._policy is not None else 0)
            sample_noise = colored_noise(
                torch.randn(c.iterations, B, n_random, c.horizon, self.action_dim,
                            generator=gen, device=latent.device, dtype=latent.dtype),
                c.noise_beta)
            policy_noise = None
            if self._policy is not None and c.num_policy:
                policy_noise = colored_noise(
                    torch.randn(B, c.num_policy, c.horizon, self.action_dim, generator=gen,
                                device=latent.device, dtype=latent.dtype), c.noise_beta)
                if c.policy_noise_steps:
                    policy_noise[:, :, c.policy_noise_steps:] = 0
            dtype = autocast_dtype(c.precision, latent.device)
            try:
                with torch.autocast(latent.device.type, dtype=dtype, enabled=dtype is not None):
                    mean, std, rewards, value, elites = self._plan_impl(
                        latent, mean, sample_noise, policy_noise, proposal_latent)
            except RuntimeError as err:  # e.g. a latent size the models do not take
                raise RuntimeError(f"LatentMPPIPlanner: planning from {self.latent_key!r} of "
                                   f"shape {tuple(latent.shape)} failed inside the models "
                                   f"(does its size match what dynamics/reward/value take? "
                                   f"pass latent_dim= to check it up front): {err}") from err
        # Under autocast the heads' outputs are bfloat16: hand back the latent's dtype.
        mean, std, rewards, value, elites = (x.to(latent.dtype) for x in
                                             (mean, std, rewards, value, elites))
        self._previous_mean = mean
        action = mean[:, 0]
        outputs = {self.action_key: action, ("planner", "mean"): mean, ("planner", "std"): std,
                   ("planner", "rewards"): rewards, ("planner", "value"): value,
                   ("planner", "elite_actions"): elites}
        for key, val in outputs.items():
            tensordict.set(key, val[0] if squeeze else val)
        return tensordict
