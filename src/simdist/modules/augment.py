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


class RandomRotate(nn.Module):
    """In-plane rotation by a uniform angle in ``[-max_deg, max_deg]`` about the centre.

    Bilinear resampling with edge pixels replicated outside the image; uint8 images come
    back rounded to uint8. ``per`` as in :class:`RandomShift`: one angle per sequence
    (``[..., T, H, W, C]``) or per image. Identity in ``eval()`` mode or with
    ``max_deg=0``. Composes with :class:`RandomShift` (e.g. ``nn.Sequential``): a camera
    that pans and rolls a little moves the image roughly this way.

    Examples:
        >>> rotate = RandomRotate(max_deg=5.0, per="frame")
        >>> images = torch.randint(0, 255, (4, 64, 64, 3), dtype=torch.uint8)
        >>> rotate(images).dtype, rotate(images).shape
        (torch.uint8, torch.Size([4, 64, 64, 3]))
        >>> rotate.eval()(images).equal(images)
        True
    """

    def __init__(self, max_deg: float = 5.0, per: str = "sequence",
                 generator: torch.Generator | None = None):
        super().__init__()
        if not 0 <= max_deg <= 180:
            raise ValueError(f"max_deg must be in [0, 180], got {max_deg}")
        if per not in SHIFT_MODES:
            raise ValueError(f"per must be one of {SHIFT_MODES}, got {per!r}")
        self.max_deg, self.per, self.generator = float(max_deg), per, generator

    def extra_repr(self) -> str:
        return f"max_deg={self.max_deg}, per={self.per!r}"

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        if not self.training or self.max_deg == 0:
            return images
        if images.dim() < 3 or (self.per == "sequence" and images.dim() < 4):
            layout = "[..., T, H, W, C]" if self.per == "sequence" else "[..., H, W, C]"
            raise ValueError(f"per={self.per!r} needs images {layout}, got shape "
                             f"{tuple(images.shape)}")
        H, W, C = images.shape[-3:]
        lead = images.shape[:-3]
        shape = lead[:-1] if self.per == "sequence" else lead
        angle = (torch.rand(shape, device=images.device, generator=self.generator) * 2 - 1)
        angle = torch.deg2rad(angle * self.max_deg)
        if self.per == "sequence":
            angle = angle[..., None].expand(lead)
        angle = angle.reshape(-1)
        cos, sin, zero = angle.cos(), angle.sin(), torch.zeros_like(angle)
        theta = torch.stack([torch.stack([cos, -sin, zero], -1),
                             torch.stack([sin, cos, zero], -1)], -2)  # [N, 2, 3]
        x = images.reshape(-1, H, W, C).permute(0, 3, 1, 2).float()
        grid = nn.functional.affine_grid(theta, list(x.shape), align_corners=False)
        out = nn.functional.grid_sample(x, grid, mode="bilinear", padding_mode="border",
                                        align_corners=False).permute(0, 2, 3, 1)
        if images.dtype == torch.uint8:
            out = out.round().clamp(0, 255)
        return out.to(images.dtype).reshape(images.shape)


class ReadingNoise(nn.Module):
    """Fresh Gaussian noise on precomputed readings ``[..., D]`` in training, none in eval.

    A readout student (:class:`~simdist.modules.ReadoutEncoder`) trains for hundreds of
    epochs on readings computed once per recorded image, so each step carries the same
    reading error every time it is sampled; deployed, every reading has a fresh error.
    Drawing new noise of the readout's own size in every update shows the student many
    errors per step, so it must rely on its dynamics rather than on any one reading.

    Args:
        std: ``[D]`` noise standard deviation per reading dimension, in its units.
        generator: optional ``torch.Generator`` for the noise.

    Examples:
        >>> noise = ReadingNoise(torch.tensor([0.1, 0.0, 0.02]))
        >>> readings = torch.zeros(4, 50, 3)
        >>> noisy = noise(readings)
        >>> noisy.shape, bool(noisy[..., 1].eq(0).all())  # a zero std leaves a dim as is
        (torch.Size([4, 50, 3]), True)
        >>> noise.eval()(readings).equal(readings)  # no noise at deployment
        True
    """

    def __init__(self, std: torch.Tensor, generator: torch.Generator | None = None):
        super().__init__()
        std = torch.as_tensor(std, dtype=torch.float32)
        if std.ndim != 1 or not torch.isfinite(std).all() or (std < 0).any():
            raise ValueError(f"std must be a 1-d tensor of finite values >= 0, got {std}")
        self.register_buffer("std", std.clone())
        self.generator = generator

    def extra_repr(self) -> str:
        return f"std={[round(v, 5) for v in self.std.tolist()]}"

    def forward(self, readings: torch.Tensor) -> torch.Tensor:
        if not readings.is_floating_point() or readings.shape[-1:] != self.std.shape:
            raise ValueError(f"ReadingNoise expects float readings [..., {len(self.std)}], "
                             f"got {readings.dtype} {tuple(readings.shape)}")
        if not self.training:
            return readings
        noise = torch.randn(readings.shape, device=readings.device, dtype=readings.dtype,
                            generator=self.generator)
        return readings + noise * self.std.to(readings.dtype)
