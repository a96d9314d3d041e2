"""Probe decoder: reconstructs observations from stop-gradient latents, for visualisation."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey
from torch import nn

from simdist.modules.heads import pixels_to_target
from simdist.objectives.common import SimdistLoss, sequence_batch


class ProbeLoss(SimdistLoss):
    """Trains ``probe(sg(z_t)) ~ target_t``; the world model never sees this loss.

    ``encode`` maps ``(observation [B,T,D], is_init [B,T])`` to latents (e.g.
    ``SimDistWorldModel.encode_sequence``) and runs under ``torch.no_grad``; with
    ``with_actions=True`` it also gets the ``action`` entry (``(observation, is_init,
    action)``: what an encoder that reads previous actions needs). Targets can be
    any vector key (e.g. privileged ``"state"`` to show torso/feet positions) or uint8
    pixels.

    Examples:
        >>> from simdist.modules import SimDistWorldModel, StateDecoder
        >>> wm = SimDistWorldModel.build(obs_dim=6, action_dim=2, size="tiny")
        >>> probe = StateDecoder(16, state_dim=4, hidden=8)
        >>> td = TensorDict({"observation": torch.randn(2, 5, 6), "state": torch.randn(2, 5, 4),
        ...                  "is_init": torch.zeros(2, 5, 1, dtype=torch.bool)}, [2, 5])
        >>> ProbeLoss(wm.encode_sequence, probe)(td)["loss_probe"].shape
        torch.Size([])
    """

    @dataclass
    class _AcceptedKeys:
        observation: NestedKey = "observation"
        target: NestedKey = "state"
        is_init: NestedKey = "is_init"
        action: NestedKey = "action"

    default_keys = _AcceptedKeys

    def __init__(self, encode, probe: nn.Module, check_inputs: bool = True,
                 with_actions: bool = False):
        super().__init__(check_inputs)
        self.encode, self.probe, self.with_actions = encode, probe, with_actions

    def trainable_parameters(self):
        return list(self.probe.parameters())

    def forward(self, td: TensorDictBase) -> TensorDict:
        B, T = sequence_batch(td)
        inputs = [self.read(td, "observation"), self.read_flag(td, "is_init", (B, T))]
        if self.with_actions:
            inputs.append(self.read(td, "action"))
        with torch.no_grad():
            latents = self.encode(*inputs)
        target = self.read(td, "target")
        target = pixels_to_target(target) if target.dtype == torch.uint8 else target
        error = (self.probe(latents) - target).pow(2)
        return self.finish(TensorDict({"loss_probe": error.mean()}, []))
