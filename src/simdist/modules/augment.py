"""Image augmentation for pixel encoders (DrQ / DrQ-v2 random shift)."""

from __future__ import annotations

import torch
from torch import nn

SHIFT_MODES = ("sequence", "frame")


class RandomShift(nn.Module):
    """DrQ's random shift: pad by ``pad`` pixels (edge replicated), crop back at random.

    Works on channels-last images ``[..., H, W, C]`` of any dtype (uint8 stays uint8:
    the shift is an index gather, no interpolation). Leading dimensions are
    ``[*batch, T]`` for ``per="sequence"`` (one shift per sequence, the same for its
    ``T`` frames, so that motion between frames stays what the camera saw) or any shape
    for ``per="frame"`` (every image its own shift, DrQ-v2). In ``eval()`` mode, or with
    ``pad=0``, images pass through unchanged.

    Args:
        pad: largest shift in pixels along each axis (DrQ: 4 for 84 px images).
        per: ``"sequence"`` (images ``[..., T, H, W, C]``, shift shared along ``T``) or
            ``"frame"``.
        generator: optional ``torch.Generator`` for the shifts.

    Examples:
        >>> shift = RandomShift(pad=4, per="sequence")
        >>> images = torch.randint(0, 255, (2, 5, 64, 64, 3), dtype=torch.uint8)
        >>> out = shift(images)
        >>> out.shape, out.dtype
        (torch.Size([2, 5, 64, 64, 3]), torch.uint8)
        >>> shift.eval()(images).equal(images)  # no shift at evaluation
        True
    """

    def __init__(self, pad: int = 4, per: str = "sequence",
                 generator: torch.Generator | None = None):
        super().__init__()
        if pad < 0:
            raise ValueError(f"pad must be >= 0, got {pad}")
        if per not in SHIFT_MODES:
            raise ValueError(f"per must be one of {SHIFT_MODES}, got {per!r}")
        self.pad, self.per, self.generator = int(pad), per, generator

    def extra_repr(self) -> str:
        return f"pad={self.pad}, per={self.per!r}"

    def shifts(self, shape: torch.Size, device) -> torch.Tensor:
        """Integer shifts ``[*shape, 2]`` (rows, columns) in ``[-pad, pad]``."""
        return torch.randint(-self.pad, self.pad + 1, (*shape, 2), device=device,
                             generator=self.generator)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        if not self.training or self.pad == 0:
            return images
        if images.dim() < 3:
            raise ValueError(f"images must be [..., H, W, C], got shape {tuple(images.shape)}")
        H, W, C = images.shape[-3:]
        lead = images.shape[:-3]
        if self.per == "sequence":
            if len(lead) < 1:
                raise ValueError("per='sequence' needs images [..., T, H, W, C]; got a single "
                                 f"image of shape {tuple(images.shape)}")
            shift = self.shifts(lead[:-1], images.device)[..., None, :].expand(*lead, 2)
        else:
            shift = self.shifts(lead, images.device)
        flat = images.reshape(-1, H, W, C)
        shift = shift.reshape(-1, 2)
        rows = (torch.arange(H, device=images.device) + shift[:, :1]).clamp(0, H - 1)  # [N, H]
        cols = (torch.arange(W, device=images.device) + shift[:, 1:]).clamp(0, W - 1)  # [N, W]
        n = torch.arange(flat.shape[0], device=images.device)[:, None, None]
        return flat[n, rows[:, :, None], cols[:, None, :]].reshape(images.shape)
