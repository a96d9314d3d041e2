"""Deployment export: one policy step as a ``torch.export`` program on plain tensors.

A TorchRL policy reads and writes a TensorDict and keeps state between calls (the
planner's warm start, the RSSM's belief). For deployment (a robot's control loop, AOTInductor,
another runtime) that state becomes explicit inputs and outputs of one step:

- :class:`SimDistPlanStep`: observation history + new observation -> history encoder ->
  latent MPPI (the planner's own tensor loop, unrolled) -> action, with the shifted history
  and the plan (the next step's warm start) as outputs. The planner's sampling noise is an
  input, so a step is a pure function: same inputs, same action.
- :class:`RecurrentPolicyStep`: observation (a TWIST student's pixels, or a Dreamer
  teacher's state) + RSSM state -> encoder -> one RSSM filtering step -> actor -> action,
  with the new RSSM state; the posterior sample's uniform noise is an input.

:func:`export_simdist_policy`, :func:`export_twist_policy` and
:func:`export_dreamer_policy` trace these with ``torch.export.export`` (batch size
dynamic by default); ``torch.export.save`` / ``torch.export.load`` store the program
(no Python code of ours needed to run it). Each step equals the TorchRL policy it comes
from, action for action, when fed the noise that policy draws (tested).

Limits: the exported step leaves out the TorchRL policies' input checks (the planner's
finite-latent check, key and shape messages) and the Dreamer policy's exploration noise
(deployment acts deterministically from the actor); a planner made with ``compile=True``
is exported from its eager loop. A SimDist policy that compensates actuation latency
(``latency_compensation > 0``) is refused: its queue of actions in flight is not an input
of the step.
"""

from __future__ import annotations

import torch
from torch import nn

from simdist.modules.rssm import RSSMState

__all__ = ["SimDistPlanStep", "RecurrentPolicyStep", "export_simdist_policy",
           "export_twist_policy", "export_dreamer_policy"]


class SimDistPlanStep(nn.Module):
    """One SimDist planning step on tensors (what ``SimDistPolicy`` does per env step).

    ``forward(history [B, K, D], observation [B, D], is_init [B, 1] bool,
    previous_mean [B, H, A], sample_noise [I, B, N, H, A], policy_noise [B, P, H, A])``
    returns ``(action [B, A], history [B, K, D], mean [B, H, A])``; feed ``history`` and
    ``mean`` back in at the next step. (For an encoder that reads the previous action,
    ``D`` is the observation and action width, and the previous action is the first of
    ``previous_mean``: the action the last step returned, so deploy the returned action as
    it is; a controller that changes it must build the history entry itself.)
    ``policy_noise`` is left out when the planner has no policy proposals.
    :meth:`draw_noise` draws the noise exactly as the planner does.

    Args:
        policy: a :class:`~simdist.agents.SimDistPolicy` (``agent.policy(...)``).

    Examples:
        >>> from simdist.agents import SimDistAgent
        >>> from simdist.modules import PlannerConfig, SimDistWorldModel
        >>> agent = SimDistAgent(SimDistWorldModel.build(10, 3, size="tiny"))
        >>> step = SimDistPlanStep(agent.policy(config=PlannerConfig(
        ...     horizon=2, num_samples=8, num_elites=2, iterations=1)))
        >>> action, history, mean = step(*step.example_inputs(batch_size=4))
        >>> action.shape, history.shape, mean.shape
        (torch.Size([4, 3]), torch.Size([4, 2, 10]), torch.Size([4, 2, 3]))
    """

    def __init__(self, policy):
        super().__init__()
        if getattr(policy, "latency_compensation", 0):
            # planning from the latent rolled through the actions in flight needs that queue
            # as a step input; a step without it would plan from the wrong state, silently
            raise ValueError(f"SimDistPlanStep: the policy compensates "
                             f"{policy.latency_compensation} steps of latency, which the "
                             "exported step does not carry; export a policy made with "
                             "latency_compensation=0")
        self.world_model, self.planner = policy.world_model, policy.planner
        config = self.planner.config
        self.uses_policy = self.planner._policy is not None and config.num_policy > 0
        self.num_random = config.num_samples - (config.num_policy if self.uses_policy else 0)

    def forward(self, history, observation, is_init, previous_mean, sample_noise,
                policy_noise=None):
        init = is_init.reshape(-1, 1, 1).bool()
        enc = self.world_model.encoder
        # the previous action is the one the last step returned (SimDistPolicy's rule)
        previous = previous_mean[:, 0] if enc.action_dim else None
        history = enc.push(history, observation, previous, is_init)
        latent = self.world_model.encode(history)
        mean = torch.zeros_like(previous_mean)
        if self.planner.config.warm_start:  # the previous plan shifted by one step
            warm = torch.cat([previous_mean[:, 1:], torch.zeros_like(previous_mean[:, :1])], 1)
            mean = torch.where(init, mean, warm)
        mean, _, _, _, _ = self.planner._plan(latent, mean, sample_noise,
                                              policy_noise if self.uses_policy else None)
        return mean[:, 0], history, mean

    def draw_noise(self, batch_size: int, generator: torch.Generator | None = None,
                   device=None) -> tuple[torch.Tensor, ...]:
        """``(sample_noise,)`` or ``(sample_noise, policy_noise)``, drawn in the planner's
        order (a generator seeded like the planner gives the planner's very draws)."""
        c, A = self.planner.config, self.planner.action_dim
        noise = (torch.randn(c.iterations, batch_size, self.num_random, c.horizon, A,
                             generator=generator, device=device),)
        if self.uses_policy:
            noise += (torch.randn(batch_size, c.num_policy, c.horizon, A, generator=generator,
                                  device=device),)
        return noise

    def example_inputs(self, batch_size: int = 1, generator=None) -> tuple[torch.Tensor, ...]:
        """Inputs of an episode's first step: empty history, ``is_init`` set, no plan."""
        enc, c = self.world_model.encoder, self.planner.config
        device = self.planner.action_low.device
        return (torch.zeros(batch_size, enc.history, enc.input_dim, device=device),
                torch.zeros(batch_size, enc.obs_dim, device=device),
                torch.ones(batch_size, 1, dtype=torch.bool, device=device),
                torch.zeros(batch_size, c.horizon, self.planner.action_dim, device=device),
                *self.draw_noise(batch_size, generator, device))


class RecurrentPolicyStep(nn.Module):
    """One step of a Dreamer/TWIST policy on tensors (``DreamerPolicy`` without noise).

    ``forward(observation, belief [B, deter], stoch [B, stoch * classes],
    prev_action [B, A], is_init [B, 1] bool, noise [B, stoch, classes])`` returns
    ``(action, belief, stoch)``; feed ``belief``, ``stoch`` and ``action`` back in.
    ``noise`` holds uniforms in (0, 1) for the posterior's Gumbel-max sample (what
    ``torch.rand`` gives; the TorchRL policy draws them with ``torch.rand_like``).

    Args:
        world_model: supplies ``encoder`` and ``rssm`` (a TWIST student, or a teacher).
        actor: features -> actions in ``[-1, 1]`` (the teacher's actor for TWIST).

    Examples:
        >>> from simdist.agents import DreamerAgent, DreamerConfig
        >>> agent = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
        >>> step = RecurrentPolicyStep(agent.world_model, agent.actor)
        >>> action, belief, stoch = step(*step.example_inputs(torch.zeros(3, 5)))
        >>> action.shape, belief.shape
        (torch.Size([3, 1]), torch.Size([3, 32]))
    """

    def __init__(self, world_model, actor):
        super().__init__()
        self.world_model, self.actor = world_model, actor

    def forward(self, observation, belief, stoch, prev_action, is_init, noise):
        rssm = self.world_model.rssm
        keep = (~is_init.reshape(-1, 1).bool()).to(belief.dtype)
        embed = self.world_model.encoder(observation)
        state = rssm.filter_step(RSSMState(belief, stoch), prev_action, embed, keep, noise)
        return self.actor(state.features()), state.belief, state.stoch

    def example_inputs(self, observation: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Inputs of an episode's first step for a batch of ``observation``."""
        rssm, B, device = self.world_model.rssm, observation.shape[0], observation.device
        return (observation, torch.zeros(B, rssm.deter_dim, device=device),
                torch.zeros(B, rssm.stoch_dim, device=device),
                torch.zeros(B, rssm.action_dim, device=device),
                torch.ones(B, 1, dtype=torch.bool, device=device),
                torch.rand(B, rssm.stoch, rssm.classes, device=device))


def _export(module: nn.Module, inputs: tuple, dynamic_batch: bool, batch_dims: tuple):
    module = module.eval()
    dynamic = None
    if dynamic_batch:
        batch = torch.export.Dim("batch", min=1, max=65536)
        dynamic = tuple({dim: batch} for dim in batch_dims)
    with torch.no_grad():
        return torch.export.export(module, inputs, dynamic_shapes=dynamic)


def export_simdist_policy(policy, batch_size: int = 2, dynamic_batch: bool = True):
    """``torch.export`` of one SimDist planning step (:class:`SimDistPlanStep`).

    Args:
        policy: ``agent.policy(action_spec=env.action_spec, config=...)``; its planner
            config, bounds and world model are baked into the program.
        batch_size: batch of the example inputs traced (use >= 2 with ``dynamic_batch``:
            torch.export specialises a traced size of 1).
        dynamic_batch: let the program take any batch size.

    Returns:
        a ``torch.export.ExportedProgram``; ``program.module()(*inputs)`` runs it with
        the inputs of :meth:`SimDistPlanStep.forward`.

    Examples:
        >>> from simdist.agents import SimDistAgent
        >>> from simdist.modules import PlannerConfig, SimDistWorldModel
        >>> agent = SimDistAgent(SimDistWorldModel.build(10, 3, size="tiny"))
        >>> policy = agent.policy(config=PlannerConfig(horizon=2, num_samples=8,
        ...                                            num_elites=2, iterations=1))
        >>> program = export_simdist_policy(policy)
        >>> step = SimDistPlanStep(policy)
        >>> inputs = step.example_inputs(batch_size=5, generator=torch.Generator().manual_seed(0))
        >>> all(torch.equal(a, b) for a, b in zip(program.module()(*inputs), step(*inputs)))
        True
    """
    step = SimDistPlanStep(policy)
    inputs = step.example_inputs(batch_size)
    return _export(step, inputs, dynamic_batch, (0, 0, 0, 0, 1, 0)[:len(inputs)])


def _export_recurrent(world_model, actor, observation, dynamic_batch: bool):
    step = RecurrentPolicyStep(world_model, actor)
    return _export(step, step.example_inputs(observation), dynamic_batch, (0,) * 6)


def export_twist_policy(twist, batch_size: int = 2, dynamic_batch: bool = True):
    """``torch.export`` of one TWIST deployment step: the student's pixel encoder and RSSM
    filtering step, then the teacher's actor (:class:`RecurrentPolicyStep`).

    Args:
        twist: a :class:`~simdist.agents.TwistStudent` (e.g. ``TwistStudent.load(path)``).
        batch_size: batch of the example inputs traced (>= 2 with ``dynamic_batch``).
        dynamic_batch: let the program take any batch size.

    Examples:
        >>> from simdist.agents import DreamerAgent, DreamerConfig, TwistStudent
        >>> from simdist.modules import DreamerWorldModel
        >>> teacher = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
        >>> twist = TwistStudent(teacher, DreamerWorldModel.student(1, size="tiny"))
        >>> program = export_twist_policy(twist)
        >>> step = RecurrentPolicyStep(twist.student, teacher.actor)
        >>> inputs = step.example_inputs(torch.zeros(3, 64, 64, 3, dtype=torch.uint8))
        >>> all(torch.equal(a, b) for a, b in zip(program.module()(*inputs), step(*inputs)))
        True
    """
    device = next(twist.student.parameters()).device
    pixels = torch.zeros(batch_size, 64, 64, 3, dtype=torch.uint8, device=device)
    return _export_recurrent(twist.student, twist.teacher.actor, pixels, dynamic_batch)


def export_dreamer_policy(agent, batch_size: int = 2, dynamic_batch: bool = True):
    """``torch.export`` of one step of a :class:`~simdist.agents.DreamerAgent`'s policy
    (its own encoder, RSSM and actor: a TWIST teacher or a pixel Dreamer).

    Examples:
        >>> from simdist.agents import DreamerAgent, DreamerConfig
        >>> agent = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
        >>> program = export_dreamer_policy(agent)
        >>> [spec.arg.name for spec in program.graph_signature.input_specs][-6:]
        ['observation', 'belief', 'stoch', 'prev_action', 'is_init', 'noise']
    """
    device = next(agent.world_model.parameters()).device
    encoder = agent.world_model.encoder
    if agent.obs_key == "pixels":
        obs = torch.zeros(batch_size, 64, 64, 3, dtype=torch.uint8, device=device)
    else:
        obs = torch.zeros(batch_size, encoder.state_dim, device=device)
    return _export_recurrent(agent.world_model, agent.actor, obs, dynamic_batch)
