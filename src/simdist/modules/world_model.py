"""The Dreamer-style world model used by TWIST's teacher and student.

Teacher and student are the *same class* with a different encoder: the teacher encodes
privileged state with an MLP, the student encodes pixels with a CNN. The student needs no
decoder, reward or continue head (it borrows the teacher's task structure).
"""

from __future__ import annotations

import torch
from tensordict.nn import TensorDictModule
from torch import nn

from simdist.modules.encoders import PixelEncoder, StateEncoder
from simdist.modules.heads import PixelDecoder, ScalarHead, StateDecoder
from simdist.modules.rssm import RSSM, RSSMState
from simdist.modules.state_readout import ReadoutEncoder, StateReadout

# Model sizes, TD-MPC2 style: one table, named rows.
RSSM_SIZES = {
    "tiny": dict(deter_dim=32, stoch=4, classes=4, hidden_dim=32, embed=32, head=32, depth=4),
    "compact": dict(deter_dim=64, stoch=8, classes=8, hidden_dim=64, embed=64, head=64,
                    depth=16),
    "small": dict(deter_dim=200, stoch=32, classes=32, hidden_dim=200, embed=256, head=200,
                  depth=16),
    "paper": dict(deter_dim=600, stoch=32, classes=32, hidden_dim=600, embed=512, head=400,
                  depth=48),
}


def _size(size: str) -> dict:
    if size not in RSSM_SIZES:
        raise ValueError(f"unknown model size {size!r}; valid: {', '.join(RSSM_SIZES)}")
    return RSSM_SIZES[size]


class DreamerWorldModel(nn.Module):
    """Encoder + RSSM, optionally with decoder, reward and continue heads.

    Verbs: :meth:`observe` (sequences -> posterior states), :meth:`imagine` (given
    actions), :meth:`imagine_with_policy`, :meth:`reward`, :meth:`decode`.

    Data layout: TorchRL stores, at index ``t``, the observation ``o_t``, the action
    ``a_t`` taken after it, and ``("next", ...)`` readings ``o_{t+1}, r_{t+1}``. The model
    filters the *next* observations: step ``t`` advances with ``a_t`` and conditions on
    ``o_{t+1}``, whose reward is ``("next", "reward")[t]``. ``is_init[t]`` (``o_t`` starts
    an episode) resets the state before step ``t``.

    Examples:
        >>> wm = DreamerWorldModel.teacher(state_dim=5, action_dim=1, size="tiny")
        >>> out = wm.observe(torch.randn(2, 6, 5), torch.randn(2, 6, 1),
        ...                  torch.zeros(2, 6, dtype=torch.bool))
        >>> wm.reward(wm.features(out)).shape
        torch.Size([2, 6, 1])
        >>> student = DreamerWorldModel.student(action_dim=1, size="tiny")
        >>> type(student.rssm) is type(wm.rssm)
        True
    """

    def __init__(self, encoder: nn.Module, rssm: RSSM, decoder: nn.Module | None = None,
                 reward_head: nn.Module | None = None, continue_head: nn.Module | None = None):
        super().__init__()
        self.encoder, self.rssm = encoder, rssm
        self.decoder, self.reward_head, self.continue_head = decoder, reward_head, continue_head

    @classmethod
    def teacher(cls, state_dim: int, action_dim: int, size: str = "small",
                continue_head: bool = False) -> DreamerWorldModel:
        """State-based TWIST teacher: 3-layer ELU MLP encoder, state decoder, reward head."""
        s = _size(size)
        rssm = RSSM(s["embed"], action_dim, s["deter_dim"], s["stoch"], s["classes"],
                    s["hidden_dim"])
        return cls(StateEncoder(state_dim, s["embed"], s["embed"], layers=3), rssm,
                   StateDecoder(rssm.feature_dim, state_dim, s["head"]),
                   ScalarHead(rssm.feature_dim, s["head"]),
                   ScalarHead(rssm.feature_dim, s["head"]) if continue_head else None)

    @classmethod
    def student(cls, action_dim: int, size: str = "small", depth: int | None = None,
                norm: str | None = None, input_norm: str = "fixed",
                arch: str = "dreamer") -> DreamerWorldModel:
        """Pixel-based TWIST student: CNN encoder, the same RSSM class, no heads.

        ``depth`` (default: the size's), ``norm``, ``input_norm`` and ``arch`` configure
        the :class:`PixelEncoder` (``arch="keypoints"``: ``embed // 2`` spatial-softmax
        keypoints); the RSSM sizes always follow ``size`` (the teacher's).
        """
        s = _size(size)
        encoder = PixelEncoder(depth=depth or s["depth"], norm=norm, input_norm=input_norm,
                               arch=arch, keypoints=max(1, s["embed"] // 2))
        rssm = RSSM(encoder.embed_dim, action_dim, s["deter_dim"], s["stoch"], s["classes"],
                    s["hidden_dim"])
        return cls(encoder, rssm)

    @classmethod
    def readout_student(cls, readout: StateReadout, action_dim: int,
                        size: str = "small") -> DreamerWorldModel:
        """A TWIST student that sees through a frozen :class:`StateReadout`: pixels ->
        readout -> the teacher's kind of state encoder (of the read dimensions) -> RSSM;
        no heads. Only the state encoder and the RSSM learn.
        """
        s = _size(size)
        encoder = ReadoutEncoder(readout, StateEncoder(readout.out_dim, s["embed"], s["embed"],
                                                       layers=3))
        rssm = RSSM(encoder.embed_dim, action_dim, s["deter_dim"], s["stoch"], s["classes"],
                    s["hidden_dim"])
        return cls(encoder, rssm)

    @classmethod
    def pixel_dreamer(cls, action_dim: int, size: str = "small",
                      encoder: str = "dreamer") -> DreamerWorldModel:
        """Dreamer from pixels (baseline): CNN encoder, pixel decoder, reward head;
        ``encoder="keypoints"`` reads the image with spatial-softmax keypoints instead
        (:class:`PixelEncoder` ``arch``), the decoder stays the CNN's."""
        s = _size(size)
        model = cls.student(action_dim, size, arch=encoder)
        model.decoder = PixelDecoder(model.rssm.feature_dim, s["depth"])
        model.reward_head = ScalarHead(model.rssm.feature_dim, s["head"])
        return model

    @classmethod
    def pixel_state_recon(cls, action_dim: int, state_dim: int, size: str = "small",
                          encoder: str = "dreamer") -> DreamerWorldModel:
        """Dreamer State Recon. (TWIST baseline): CNN (or ``encoder="keypoints"``)
        encoder, a decoder of the privileged *state* instead of the image, reward head."""
        s = _size(size)
        model = cls.student(action_dim, size, arch=encoder)
        model.decoder = StateDecoder(model.rssm.feature_dim, state_dim, s["head"])
        model.reward_head = ScalarHead(model.rssm.feature_dim, s["head"])
        return model

    # -- verbs ----------------------------------------------------------------------------
    def observe(self, next_obs: torch.Tensor, action: torch.Tensor, is_init: torch.Tensor,
                state: RSSMState | None = None, noise: torch.Tensor | None = None) -> dict:
        """Posterior states for ``[B, T]`` slices; adds ``"embed"`` to the RSSM outputs."""
        embed = self.encoder(next_obs)
        out = self.rssm.observe(embed, action, is_init, state, noise)
        out["embed"] = embed
        return out

    @staticmethod
    def features(states: dict) -> torch.Tensor:
        return torch.cat([states["belief"], states["stoch"]], -1)

    @staticmethod
    def state_at(states: dict) -> RSSMState:
        return RSSMState(states["belief"], states["stoch"])

    def imagine(self, state: RSSMState, actions: torch.Tensor, noise=None) -> dict:
        return self.rssm.imagine(state, actions, noise)

    def imagine_with_policy(self, state: RSSMState, policy, horizon: int, **kwargs) -> dict:
        return self.rssm.imagine_with_policy(state, policy, horizon, **kwargs)

    def reward(self, features: torch.Tensor) -> torch.Tensor:
        if self.reward_head is None:
            raise RuntimeError("this world model has no reward head (a TWIST student borrows "
                               "the teacher's)")
        return self.reward_head(features)

    def decode(self, features: torch.Tensor) -> torch.Tensor:
        if self.decoder is None:
            raise RuntimeError("this world model has no decoder")
        return self.decoder(features)

    def observe_module(self, obs_key="state", prefix: str = "teacher",
                       action_key="action", is_init_key="is_init") -> TensorDictModule:
        """This model's filtering as a ``TensorDictModule`` with declared keys.

        Reads ``("next", obs_key)``, ``action_key``, ``is_init_key``; writes
        ``(prefix, "belief" | "stoch" | "prior_logits" | "posterior_logits")``.
        """
        return TensorDictModule(
            _Observe(self), in_keys=[("next", obs_key), action_key, is_init_key],
            out_keys=[(prefix, k) for k in ("belief", "stoch", "prior_logits",
                                            "posterior_logits")])


class _Observe(nn.Module):
    def __init__(self, model: DreamerWorldModel):
        super().__init__()
        self.model = model

    def forward(self, next_obs, action, is_init):
        out = self.model.observe(next_obs, action, is_init.reshape(is_init.shape[:2]))
        return out["belief"], out["stoch"], out["prior_logits"], out["posterior_logits"]
