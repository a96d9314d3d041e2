"""A frozen image -> state sensor, and the encoder that puts it in front of a student RSSM.

A TWIST student whose CNN learns only from the teacher's latents reads the cartpole's pole
too coarsely to balance it (docs/methods.md, section 2.7). :class:`StateReadout` is a CNN
and a linear head fitted *supervised* to the privileged positions of many domain-randomised
renders (``experiments/twist_readout_scale.py``), then frozen; :class:`ReadoutEncoder`
feeds its readings to a trainable state encoder, so that the student RSSM learns the
velocities and the teacher's latent from the readings, as a state student would.

A readout fitted precisely on a small domain (the balancing region) extrapolates outside
it: a student whose pole swings out of that box reads nonsense and cannot bring it back.
A second, coarse readout fitted on every pose can be attached as the ``fallback``: it
answers wherever the precise readout's own reading leaves its ``gate`` box or the
fallback's reading leaves the ``fallback_gate`` box (a precise readout shown a hanging
pole may still read an upright one, so the coarse reading has a say; docs/findings.md,
"What the perception gap is made of").
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import torch
from torch import nn

from simdist.modules.checks import check_last_dims
from simdist.modules.encoders import PixelEncoder, StateEncoder
from simdist.utils.checkpoint import CorruptCheckpointError, load_checkpoint
from simdist.utils.stages import read_json


class StateReadout(nn.Module):
    """Frozen CNN + linear head: a 64x64 image -> some state dimensions, in the state's units.

    The head predicts all ``state_dim`` standardised dimensions (the ones one image cannot
    show, e.g. velocities, are zero rows); ``dims`` picks what the readout returns. Its
    ``domain`` is the box of those dimensions it was fitted on: outside it, its readings
    are extrapolations (:meth:`covers`).

    The module is frozen (no gradient, always in evaluation mode). It reads ``uint8``
    images ``[..., 64, 64, 3]``; a floating tensor ``[..., len(dims)]`` is taken as
    readings computed earlier by :meth:`read` and passed through, so that a student can
    train on readings computed once (the readout is frozen, so they are the same).

    Args:
        encoder: the CNN (a :class:`~simdist.modules.PixelEncoder`).
        state_dim: the size of the state the head predicts.
        dims: the state dimensions returned.
        mean: the standardisation's mean of those dimensions (``[len(dims)]``).
        std: its standard deviation (``[len(dims)]``).
        domain: ``(low, high)`` per returned dimension, the fitted region; ``None``: all.
        fallback: an optional readout of the same dimensions fitted on a wider domain,
            whose reading is returned instead of this readout's extrapolation wherever
            this readout's reading lies outside ``gate`` or the fallback's lies outside
            ``fallback_gate``.
        gate: ``(low, high)`` per returned dimension: this readout answers only where its
            own reading lies inside; default: ``domain``. Only with a ``fallback``.
        fallback_gate: ``(low, high)`` per returned dimension: ... and where the
            fallback's reading lies inside; default: no condition. Only with a fallback.

    Examples:
        >>> readout = StateReadout(PixelEncoder(4), state_dim=5, dims=[0, 1, 2])
        >>> images = torch.zeros(2, 7, 64, 64, 3, dtype=torch.uint8)
        >>> readout(images).shape
        torch.Size([2, 7, 3])
        >>> torch.equal(readout(readout(images)), readout(images))  # readings pass through
        True
        >>> any(p.requires_grad for p in readout.parameters())
        False
        >>> wide = StateReadout(PixelEncoder(4), state_dim=5, dims=[0, 1, 2])
        >>> gated = StateReadout(PixelEncoder(4), 5, [0, 1, 2], fallback=wide,
        ...                      gate=([-0.9, 0.9, -0.3], [0.9, 2.0, 0.3]),
        ...                      fallback_gate=([-9.0, 0.3, -9.0], [9.0, 2.0, 9.0]))
        >>> gated(images).shape
        torch.Size([2, 7, 3])
    """

    def __init__(self, encoder: PixelEncoder, state_dim: int, dims: list[int],
                 mean: torch.Tensor | None = None, std: torch.Tensor | None = None,
                 domain: tuple[list[float], list[float]] | None = None,
                 fallback: StateReadout | None = None,
                 gate: tuple[list[float], list[float]] | None = None,
                 fallback_gate: tuple[list[float], list[float]] | None = None):
        super().__init__()
        dims = [int(d) for d in dims]
        if not dims or len(set(dims)) != len(dims) or not all(0 <= d < state_dim for d in dims):
            raise ValueError(f"dims must be distinct indices in [0, {state_dim}), got {dims}")
        self.encoder = encoder
        self.head = nn.Linear(encoder.embed_dim, state_dim)
        self.state_dim = state_dim
        n = len(dims)
        self.register_buffer("mean", torch.zeros(n) if mean is None else mean.float().clone())
        self.register_buffer("std", torch.ones(n) if std is None else std.float().clone())
        self.register_buffer("dims", torch.tensor(dims))
        for name in ("mean", "std"):
            check_last_dims(name, getattr(self, name), (n,))
        self.domain = domain = _box("domain", domain, n)
        if fallback is not None and (fallback.state_dim != state_dim
                                     or fallback.dims.tolist() != dims):
            raise ValueError(f"the fallback readout reads dims {fallback.dims.tolist()} of "
                             f"a {fallback.state_dim}-d state; this one {dims} of {state_dim}")
        if (gate is not None or fallback_gate is not None) and fallback is None:
            raise ValueError("a gate needs a fallback readout")
        gate = domain if gate is None and fallback is not None else gate
        if fallback is not None and gate is None:
            raise ValueError("a fallback readout needs a gate (or a domain) to switch on")
        self.fallback = fallback
        self.gate, self.fallback_gate = (_box(name, box, n) for name, box in (
            ("gate", gate), ("fallback_gate", fallback_gate)))
        self.requires_grad_(False)
        self.eval()

    @property
    def out_dim(self) -> int:
        return len(self.dims)

    def train(self, mode: bool = True) -> StateReadout:
        return super().train(False)  # frozen: stays in evaluation mode

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.dtype == torch.uint8:
            check_last_dims("pixels", x, (64, 64, 3))
            batch = x.shape[:-3]
            out = self.head(self.encoder(x.reshape(-1, *x.shape[-3:])))
            out = out.index_select(-1, self.dims) * self.std + self.mean
            out = out.reshape(*batch, self.out_dim)
            if self.fallback is None:
                return out
            coarse = self.fallback(x)
            return torch.where(self.gated(out, coarse)[..., None], out, coarse)
        if not x.is_floating_point() or x.shape[-1] != self.out_dim:
            raise ValueError(f"StateReadout reads uint8 images [..., 64, 64, 3] or passes "
                             f"precomputed readings [..., {self.out_dim}]; got "
                             f"{x.dtype} {tuple(x.shape)}")
        return x

    @torch.no_grad()
    def read(self, pixels: torch.Tensor, chunk: int = 500) -> torch.Tensor:
        """The readings of ``pixels`` ``[N, 64, 64, 3]`` (uint8), ``chunk`` images at a time."""
        if pixels.dtype != torch.uint8 or pixels.ndim != 4:
            raise ValueError(f"read expects uint8 images [N, 64, 64, 3], got "
                             f"{pixels.dtype} {tuple(pixels.shape)}")
        device = self.mean.device
        return torch.cat([self(pixels[i:i + chunk].to(device)).cpu()
                          for i in range(0, len(pixels), chunk)])

    def with_fallback(self, fallback: StateReadout | None,
                      gate: tuple[list[float], list[float]] | None = None,
                      fallback_gate: tuple[list[float], list[float]] | None = None
                      ) -> StateReadout:
        """This readout (its weights shared) with another ``fallback`` and gates, or with
        none (``fallback=None``): what it reads alone, extrapolating outside its domain."""
        out = StateReadout(self.encoder, self.state_dim, self.dims.tolist(), self.mean,
                           self.std, self.domain, fallback=fallback, gate=gate,
                           fallback_gate=fallback_gate)
        out.head = self.head
        return out

    def without_fallback(self) -> StateReadout:
        """This readout alone (:meth:`with_fallback` of none)."""
        return self.with_fallback(None)

    def gated(self, readings: torch.Tensor, coarse: torch.Tensor) -> torch.Tensor:
        """Mask ``[...]`` of where this readout answers: its ``readings`` ``[..., out_dim]``
        inside ``gate`` and the fallback's ``coarse`` readings inside ``fallback_gate``."""
        if self.fallback is None:
            raise ValueError("this readout has no fallback, hence no gate")
        inside = _inside(readings, self.gate)
        return inside if self.fallback_gate is None else inside & _inside(
            coarse, self.fallback_gate)

    def covers(self, state: torch.Tensor) -> torch.Tensor:
        """Mask ``[...]`` of the states ``[..., state_dim]`` inside the fitted domain (of
        this readout; a fallback's wider domain does not count: its readings are coarse)."""
        check_last_dims("state", state, (self.state_dim,))
        if self.domain is None:
            return torch.ones(state.shape[:-1], dtype=torch.bool, device=state.device)
        return _inside(state.index_select(-1, self.dims.to(state.device)), self.domain)

    def describe(self) -> dict:
        """Plain data that rebuilds this readout (untrained) with :meth:`from_description`."""
        enc = self.encoder
        if getattr(enc, "arch", None) != "dreamer":  # what from_description rebuilds
            raise ValueError(f"only a PixelEncoder of arch 'dreamer' is described, got "
                             f"{type(enc).__name__} {getattr(enc, 'arch', '')!r}")
        return {"depth": int(enc.net[0].out_channels), "norm": enc.norm,
                "input_norm": enc.input_norm, "state_dim": int(self.state_dim),
                "dims": self.dims.tolist(),
                "domain": None if self.domain is None else [list(s) for s in self.domain],
                **({} if self.fallback is None else {
                    "fallback": self.fallback.describe(),
                    "gate": [list(s) for s in self.gate],
                    "fallback_gate": None if self.fallback_gate is None else [
                        list(s) for s in self.fallback_gate]})}

    @classmethod
    def from_description(cls, desc: dict) -> StateReadout:
        try:
            encoder = PixelEncoder(desc["depth"], norm=desc["norm"], input_norm=desc["input_norm"])
            fallback = (cls.from_description(desc["fallback"]) if desc.get("fallback")
                        else None)
            return cls(encoder, desc["state_dim"], desc["dims"], domain=desc.get("domain"),
                       fallback=fallback, gate=desc.get("gate"),
                       fallback_gate=desc.get("fallback_gate"))
        except (KeyError, TypeError) as e:
            raise ValueError(f"not a StateReadout description ({e!r}): {desc}") from None

    def save(self, path: str | os.PathLike, meta: dict | None = None) -> Path:
        """Writes the weights to ``path`` and the description (+ ``meta``) beside it as
        ``path`` with a ``.json`` suffix."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        torch.save(self.state_dict(), tmp)
        os.replace(tmp, path)
        path.with_suffix(".json").write_text(
            json.dumps({**(meta or {}), "readout": self.describe()}, indent=1) + "\n")
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> StateReadout:
        """A readout written by :meth:`save` (weights only: no pickled code runs)."""
        path = Path(path)
        sidecar = path.with_suffix(".json")
        for p in (path, sidecar):
            if not p.exists():
                raise FileNotFoundError(f"no readout file {p} (a readout is a .pt of weights "
                                        f"and a .json description beside it)")
        desc = read_json(sidecar, "readout description",
                         recovery=f"restore it, or refit the readout that {path} belongs to")
        if not isinstance(desc, dict) or "readout" not in desc:
            raise ValueError(f"{sidecar} has no 'readout' description")
        readout = cls.from_description(desc["readout"])
        # weights only, and an error that names the file, never torch's advice to retry
        # with weights_only=False (which would run pickled code)
        state = load_checkpoint(path, recovery=f"refit the readout (its record: {sidecar})")
        if not isinstance(state, dict):
            raise CorruptCheckpointError(f"{path} holds a {type(state).__name__}, not a "
                                         "readout's weights")
        try:
            readout.load_state_dict(state)
        except (RuntimeError, TypeError, AttributeError) as e:
            raise ValueError(f"{path} does not match its description {sidecar}: {e}") from None
        for name, value in state.items():
            if value.is_floating_point() and not torch.isfinite(value).all():
                raise ValueError(f"{path}: {name} holds NaN or inf")
        return readout


def _box(name: str, box, n: int) -> tuple[list[float], list[float]] | None:
    """``box`` as ``(low, high)`` lists of ``n`` floats with low < high, or None."""
    if box is None:
        return None
    low, high = (list(map(float, side)) for side in box)
    if len(low) != n or len(high) != n or any(lo >= hi for lo, hi in zip(low, high)):
        raise ValueError(f"{name} must be (low, high) with {n} values each and low < high, "
                         f"got {box}")
    return low, high


def _inside(values: torch.Tensor, box: tuple[list[float], list[float]]) -> torch.Tensor:
    """Mask ``[...]`` of ``values`` ``[..., n]`` inside ``box`` on every dimension."""
    low = torch.tensor(box[0], device=values.device, dtype=values.dtype)
    high = torch.tensor(box[1], device=values.device, dtype=values.dtype)
    return ((values >= low) & (values <= high)).all(-1)


class ReadoutEncoder(nn.Module):
    """Pixels -> frozen :class:`StateReadout` -> trainable :class:`StateEncoder`.

    The encoder of a "readout student": its RSSM sees an embedding of a few read state
    dimensions, as a state student's sees the state. Training batches may hold the
    readout's readings instead of images (:meth:`StateReadout.read`).

    Examples:
        >>> readout = StateReadout(PixelEncoder(4), state_dim=5, dims=[0, 1, 2])
        >>> encoder = ReadoutEncoder(readout, StateEncoder(3, embed_dim=16, hidden=16))
        >>> encoder(torch.zeros(4, 64, 64, 3, dtype=torch.uint8)).shape
        torch.Size([4, 16])
        >>> sum(p.numel() for p in encoder.parameters() if p.requires_grad) == sum(
        ...     p.numel() for p in encoder.encoder.parameters())
        True
    """

    def __init__(self, readout: StateReadout, encoder: StateEncoder):
        super().__init__()
        if encoder.state_dim != readout.out_dim:
            raise ValueError(f"the state encoder reads {encoder.state_dim} values, the "
                             f"readout gives {readout.out_dim}")
        self.readout, self.encoder = readout, encoder
        self.embed_dim = encoder.embed_dim

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.encoder(self.readout(x))
