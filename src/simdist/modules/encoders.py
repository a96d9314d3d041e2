"""Observation encoders: state MLP (TWIST teacher), Dreamer pixel CNN, SimDist history MLP."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from simdist.modules.checks import check_finite, check_last_dims


def mlp(in_dim: int, out_dim: int, hidden: int, layers: int,
        activation: type[nn.Module] = nn.ELU, norm: bool = True) -> nn.Sequential:
    """``layers`` hidden layers of ``hidden`` units (LayerNorm + activation), then a linear."""
    blocks, dim = [], in_dim
    for _ in range(layers):
        blocks += [nn.Linear(dim, hidden)]
        if norm:
            blocks += [nn.LayerNorm(hidden)]
        blocks += [activation()]
        dim = hidden
    blocks.append(nn.Linear(dim, out_dim))
    return nn.Sequential(*blocks)


class StateEncoder(nn.Module):
    """MLP over a privileged state vector (TWIST teacher: 3 x 512 ELU).

    Examples:
        >>> enc = StateEncoder(5, embed_dim=32, hidden=64)
        >>> enc(torch.zeros(2, 7, 5)).shape
        torch.Size([2, 7, 32])
    """

    def __init__(self, state_dim: int, embed_dim: int = 512, hidden: int = 512, layers: int = 3):
        super().__init__()
        self.state_dim, self.embed_dim = state_dim, embed_dim
        self.net = mlp(state_dim, embed_dim, hidden, layers - 1)

    def forward(self, state: torch.Tensor) -> torch.Tensor:
        check_last_dims("state", state, (self.state_dim,))
        return self.net(state)


class PixelEncoder(nn.Module):
    """Convolutional encoder for 64x64 RGB (uint8, channels last).

    ``arch="dreamer"`` (default): four 4x4 stride-2 convolutions with
    ``depth * (1, 2, 4, 8)`` channels, as in DreamerV2; output is the flattened
    ``8 * depth * 2 * 2`` feature vector.

    ``arch="keypoints"``: a spatial-softmax encoder (deep spatial autoencoders, Finn et
    al. 2016): 3x3 convolutions of ``2 * depth`` channels with strides 2, 2, 1, then one
    of ``keypoints`` channels, all on a 16x16 map; each channel's softmax over the map
    gives the expected image coordinates of one learned feature, so the output is
    ``2 * keypoints`` coordinates in ``[-1, 1]``. It is built for reading *where* things
    are (a thin pole's tip relative to its cart), which a flatten-then-linear head has to
    learn position by position. Measured with the TWIST probe (docs/findings.md):
    held-out R^2 of cart position / pole tilt 0.78 / 0.38 after 600 updates against
    0.48 / 0.02 for the Dreamer CNN, at ~1.6x its compute per image.

    Args:
        depth: channels of the first convolution (DreamerV2: 48; ``"compact"``: 16).
        image_size: must be 64.
        norm: ``None`` (DreamerV2) or ``"layer"``: a LayerNorm over the channels of
            every pixel after each convolution, before the activation (DreamerV3).
        input_norm: ``"fixed"`` maps uint8 to ``[-0.5, 0.5]``; ``"image"`` standardises
            each image per channel (zero mean, unit std over its pixels), which removes
            a global colour or brightness shift before the first convolution.
        arch: ``"dreamer"`` or ``"keypoints"``.
        keypoints: number of spatial-softmax keypoints (``arch="keypoints"`` only).
        channels: channels of one input image (3: RGB; ``3 * k`` for ``k`` RGB frames
            stacked on the channel axis, as a memoryless pixel actor reads them).

    Examples:
        >>> enc = PixelEncoder(depth=8)
        >>> enc(torch.zeros(3, 64, 64, 3, dtype=torch.uint8)).shape
        torch.Size([3, 256])
        >>> PixelEncoder(depth=8, norm="layer", input_norm="image")(
        ...     torch.zeros(2, 5, 64, 64, 3, dtype=torch.uint8)).shape
        torch.Size([2, 5, 256])
        >>> PixelEncoder(depth=8, arch="keypoints", keypoints=16)(
        ...     torch.zeros(3, 64, 64, 3, dtype=torch.uint8)).shape
        torch.Size([3, 32])
    """

    NORMS = (None, "layer")
    INPUT_NORMS = ("fixed", "image")
    ARCHS = ("dreamer", "keypoints")

    def __init__(self, depth: int = 32, image_size: int = 64, norm: str | None = None,
                 input_norm: str = "fixed", arch: str = "dreamer", keypoints: int = 32,
                 channels: int = 3):
        super().__init__()
        if image_size != 64:
            raise ValueError(f"PixelEncoder expects 64x64 images, got image_size={image_size}")
        if norm not in self.NORMS:
            raise ValueError(f"norm must be one of {self.NORMS}, got {norm!r}")
        if input_norm not in self.INPUT_NORMS:
            raise ValueError(f"input_norm must be one of {self.INPUT_NORMS}, got {input_norm!r}")
        if arch not in self.ARCHS:
            raise ValueError(f"arch must be one of {self.ARCHS}, got {arch!r}")
        if depth < 1 or keypoints < 1 or channels < 1:
            raise ValueError(f"depth, keypoints and channels must be >= 1, got {depth}, "
                             f"{keypoints}, {channels}")
        self.image_size, self.norm, self.input_norm = image_size, norm, input_norm
        self.arch, self.keypoints, self.channels = arch, keypoints, channels
        if arch == "keypoints":
            self.net = _keypoint_net(depth, norm, keypoints, channels)
            self.embed_dim = 2 * keypoints
            return
        layers = []
        for i in range(4):
            layers.append(nn.Conv2d(channels, depth * 2**i, 4, stride=2, bias=norm is None))
            if norm == "layer":
                layers.append(ChannelLayerNorm(depth * 2**i))
            layers.append(nn.ELU())
            channels = depth * 2**i
        self.net = nn.Sequential(*layers, nn.Flatten())
        self.embed_dim = channels * 2 * 2

    def forward(self, pixels: torch.Tensor) -> torch.Tensor:
        check_last_dims("pixels", pixels, (self.image_size, self.image_size, self.channels))
        lead = pixels.shape[:-3]
        x = pixels.reshape(-1, *pixels.shape[-3:]).permute(0, 3, 1, 2)
        x = x.float() / 255.0 - 0.5 if pixels.dtype == torch.uint8 else x.float()
        if self.input_norm == "image":
            std, mean = torch.std_mean(x, dim=(2, 3), keepdim=True)
            x = (x - mean) / (std + 1e-2)
        return self.net(x).reshape(*lead, self.embed_dim)


def _keypoint_net(depth: int, norm: str | None, keypoints: int,
                  channels: int = 3) -> nn.Sequential:
    layers = []
    for stride in (2, 2, 1):  # 64 -> 32 -> 16 -> 16
        layers.append(nn.Conv2d(channels, 2 * depth, 3, stride=stride, padding=1,
                                bias=norm is None))
        if norm == "layer":
            layers.append(ChannelLayerNorm(2 * depth))
        layers.append(nn.ELU())
        channels = 2 * depth
    layers += [nn.Conv2d(channels, keypoints, 3, padding=1), SpatialSoftmax()]
    return nn.Sequential(*layers)


class SpatialSoftmax(nn.Module):
    """``[N, C, H, W]`` maps -> ``[N, 2C]`` expected coordinates ``(x_1..x_C, y_1..y_C)``.

    Each channel's softmax over its ``H x W`` positions weighs a grid spanning
    ``[-1, 1]`` in both directions (left/top = -1), so a channel that is large at one
    position returns that position's coordinates.

    Examples:
        >>> maps = torch.full((1, 1, 3, 5), -1e4); maps[0, 0, 2, 1] = 0.0  # row 2, column 1
        >>> SpatialSoftmax()(maps)  # x of column 1 of 5, y of row 2 of 3
        tensor([[-0.5000,  1.0000]])
    """

    def forward(self, maps: torch.Tensor) -> torch.Tensor:
        N, C, H, W = maps.shape
        weights = maps.flatten(2).softmax(-1).view(N, C, H, W)
        xs = torch.linspace(-1.0, 1.0, W, device=maps.device, dtype=maps.dtype)
        ys = torch.linspace(-1.0, 1.0, H, device=maps.device, dtype=maps.dtype)
        return torch.cat([(weights.sum(2) * xs).sum(-1), (weights.sum(3) * ys).sum(-1)], -1)


class ChannelLayerNorm(nn.LayerNorm):
    """LayerNorm over the channels of each pixel of ``[N, C, H, W]`` maps (DreamerV3).

    Examples:
        >>> ChannelLayerNorm(4)(torch.randn(2, 4, 3, 3)).mean(1).abs().max().item() < 1e-5
        True
    """

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return super().forward(x.permute(0, 2, 3, 1)).permute(0, 3, 1, 2)


class HistoryEncoder(nn.Module):
    """SimDist encoder ``z_t = enc(o_{t-k+1..t})``: an MLP over a window of observations.

    Windows never reach across an episode start: positions before the first step of the
    current episode repeat that first observation (a robot has no history yet there).
    With ``simnorm_groups`` the latent is split into groups, each softmax-normalised
    (TD-MPC2's SimNorm), which keeps latents bounded without a reconstruction loss.
    ``ignored_inputs`` lists observation dimensions the encoder does not read (e.g. sensors
    a world model should not depend on); the windows keep their full width.

    With ``action_dim`` > 0 every step of the window also carries the action sent one step
    before it (``[o_t, a_{t-1}]``, zeros at an episode's first step): a robot knows what
    it commanded, and with actuation latency the commands still in flight decide what
    happens next, which the observations alone cannot tell. A window then reads
    ``history + 1`` steps of a sequence (:attr:`context`).

    Examples:
        >>> enc = HistoryEncoder(obs_dim=4, history=3, latent_dim=16, hidden=32)
        >>> obs = torch.randn(2, 10, 4)
        >>> is_init = torch.zeros(2, 10, dtype=torch.bool); is_init[:, 0] = True
        >>> enc.encode_sequence(obs, is_init).shape
        torch.Size([2, 10, 16])
        >>> with_actions = HistoryEncoder(obs_dim=4, history=3, latent_dim=16, hidden=32,
        ...                               action_dim=2)
        >>> with_actions.encode_sequence(obs, is_init, torch.zeros(2, 10, 2)).shape
        torch.Size([2, 10, 16])
    """

    def __init__(self, obs_dim: int, history: int = 4, latent_dim: int = 64, hidden: int = 256,
                 layers: int = 2, simnorm_groups: int | None = 8,
                 ignored_inputs: Sequence[int] = (), action_dim: int = 0):
        super().__init__()
        if history < 1:
            raise ValueError(f"history must be >= 1, got {history}")
        if action_dim < 0:
            raise ValueError(f"action_dim must be >= 0, got {action_dim}")
        ignored = sorted({int(i) for i in ignored_inputs})
        if ignored and not (0 <= ignored[0] and ignored[-1] < obs_dim):
            raise ValueError(f"ignored_inputs must be indices in [0, {obs_dim}), got {ignored}")
        if len(ignored) == obs_dim:
            raise ValueError("ignored_inputs would hide every observation dimension")
        self.ignored_inputs = tuple(ignored)
        if simnorm_groups and latent_dim % simnorm_groups:
            raise ValueError(f"latent_dim={latent_dim} not divisible by "
                             f"simnorm_groups={simnorm_groups}")
        self.obs_dim, self.history, self.latent_dim = obs_dim, history, latent_dim
        self.action_dim = int(action_dim)
        # one step of the window: the observation, then the previous action (if read)
        self.input_dim = obs_dim + self.action_dim
        # steps of a sequence one window reads: the oldest entry's previous action too
        self.context = history + (1 if self.action_dim else 0)
        self.simnorm_groups = simnorm_groups
        self.net = mlp(self.input_dim * history, latent_dim, hidden, layers)
        # Fixed input statistics (buffers, never trained): observations mix angles,
        # velocities and contact forces whose scales differ by orders of magnitude.
        self.register_buffer("obs_mean", torch.zeros(obs_dim))
        self.register_buffer("obs_std", torch.ones(obs_dim))
        # Observation dimensions the encoder never reads (zeroed after standardisation, so
        # they carry no information). Saved only when some are ignored: state dicts without
        # ignored inputs keep their keys, and code that predates the option refuses a file
        # with a mask (unexpected key) instead of reading the hidden sensors.
        mask = torch.ones(obs_dim)
        mask[list(self.ignored_inputs)] = 0.0
        self.register_buffer("input_mask", mask, persistent=bool(self.ignored_inputs))

    def set_normalisation(self, mean: torch.Tensor, std: torch.Tensor, eps: float = 1e-3) -> None:
        """Standardises inputs with dataset statistics (e.g. before pretraining)."""
        check_last_dims("mean", mean, (self.obs_dim,))
        check_last_dims("std", std, (self.obs_dim,))
        check_finite("mean", mean)
        check_finite("std", std)
        self.obs_mean.copy_(mean)
        self.obs_std.copy_(std.clamp_min(eps))

    def forward(self, window: torch.Tensor) -> torch.Tensor:
        """Encodes windows ``[..., history, input_dim]`` (oldest first) into latents
        (``input_dim``: the observation, then the previous action if it is read)."""
        check_last_dims("observation window", window, (self.history, self.input_dim))
        obs = (window[..., :self.obs_dim] - self.obs_mean) / self.obs_std * self.input_mask
        # actions lie within the action bounds (about [-1, 1]): read as they are
        x = torch.cat([obs, window[..., self.obs_dim:]], -1) if self.action_dim else obs
        z = self.net(x.flatten(-2))
        return simnorm(z, self.simnorm_groups) if self.simnorm_groups else z

    def step_input(self, obs: torch.Tensor, previous_action: torch.Tensor | None) -> torch.Tensor:
        """One step of a window: ``obs [..., obs_dim]``, then ``previous_action
        [..., action_dim]`` if this encoder reads it (``None`` only when it does not)."""
        check_last_dims("observation", obs, (self.obs_dim,))
        if not self.action_dim:
            return obs
        if previous_action is None:
            raise ValueError("this encoder reads the previous action beside each observation "
                             "(action_dim > 0): pass it")
        check_last_dims("previous action", previous_action, (self.action_dim,))
        return torch.cat([obs, previous_action.to(obs.dtype)], -1)

    def push(self, history: torch.Tensor | None, obs: torch.Tensor,
             previous_action: torch.Tensor | None, is_init: torch.Tensor) -> torch.Tensor:
        """The deployment window after one step: ``history [..., history, input_dim]``
        (``None`` before the first step) shifted by one with the new step appended; where
        ``is_init [..., 1]`` is set, a new episode's window repeating its first step, whose
        previous action is zero, exactly as :meth:`windows` builds training windows."""
        start = is_init.reshape(*obs.shape[:-1], 1).bool()
        if previous_action is not None:
            previous_action = previous_action.masked_fill(start, 0.0)
        step = self.step_input(obs, previous_action).unsqueeze(-2)
        if history is None:
            return step.expand(*obs.shape[:-1], self.history, self.input_dim)
        shifted = torch.cat([history[..., 1:, :], step], -2)
        return torch.where(start[..., None], step.expand_as(shifted), shifted)

    @staticmethod
    def previous_actions(actions: torch.Tensor, is_init: torch.Tensor) -> torch.Tensor:
        """``[B, T, A]`` actions -> the action sent one step before each step (zeros at an
        episode's first step, and at a slice's first step, whose predecessor is not in it)."""
        previous = torch.cat([torch.zeros_like(actions[:, :1]), actions[:, :-1]], 1)
        return torch.where(is_init[..., None].bool(), torch.zeros_like(previous), previous)

    def windows(self, obs: torch.Tensor, is_init: torch.Tensor,
                actions: torch.Tensor | None = None) -> torch.Tensor:
        """``[B, T, D]`` sequences -> ``[B, T, history, input_dim]`` windows clamped to
        episode starts. ``actions [B, T, A]`` (the action taken at each step) are needed
        when the encoder reads previous actions and ignored otherwise."""
        check_last_dims("observation", obs, (self.obs_dim,))
        if self.action_dim:
            if actions is None:
                raise ValueError("this encoder reads the previous action beside each "
                                 "observation (action_dim > 0): pass the slices' actions")
            if actions.shape != (*obs.shape[:2], self.action_dim):
                raise ValueError(f"actions must have shape {(*obs.shape[:2], self.action_dim)} "
                                 f"to go with observations {tuple(obs.shape)}, got "
                                 f"{tuple(actions.shape)}")
            obs = self.step_input(obs, self.previous_actions(actions, is_init))
        B, T = obs.shape[:2]
        steps = torch.arange(T, device=obs.device)
        first = is_init.clone()
        first[:, 0] = True  # a slice starts a window whether or not an episode does
        episode_start = torch.cummax(torch.where(first, steps, torch.zeros_like(steps)), 1).values
        offsets = torch.arange(self.history - 1, -1, -1, device=obs.device)
        index = (steps[None, :, None] - offsets).clamp_min(0)  # [1, T, k]
        index = torch.maximum(index, episode_start[:, :, None])  # [B, T, k]
        return torch.gather(obs[:, :, None].expand(B, T, self.history, -1), 1,
                            index[..., None].expand(B, T, self.history, self.input_dim))

    def encode_sequence(self, obs: torch.Tensor, is_init: torch.Tensor,
                        actions: torch.Tensor | None = None) -> torch.Tensor:
        """Latents for every step of ``[B, T, D]`` sequences (``actions``: see
        :meth:`windows`)."""
        check_finite("observation", obs)
        if self.action_dim and actions is not None:
            check_finite("action", actions)
        return self(self.windows(obs, is_init, actions))


# float32 lanes of one vector register of the CPU kernels torch dispatches to, where
# measured. On AVX512 cores torch's softmax over a last dimension shorter than that (a
# SimNorm group of 8) runs ~15x slower per element than over 16, and was a third of the
# recipe's planner time (benchmarks/simnorm_softmax.py); AVX2 and other CPUs are not
# measured and keep the direct call.
_SHORT_GROUP_LANES = {"AVX512": 16}.get(torch.backends.cpu.get_cpu_capability(), 0)


def simnorm(z: torch.Tensor, groups: int) -> torch.Tensor:
    """TD-MPC2's simplicial normalisation: softmax within each of ``groups`` chunks.

    Computed in at least float32, so that under bfloat16 autocast the latent (what the
    consistency loss and the planner compare) keeps full precision; only the MLPs' matmuls
    run in the lower precision. On AVX512 CPUs a group shorter than a vector register is
    normalised along a non-last dimension (the same softmax through torch's other kernel,
    equal to ~1e-7), which is several times faster there.

    Examples:
        >>> z = simnorm(torch.randn(2, 16), groups=2)
        >>> torch.allclose(z.reshape(2, 2, 8).sum(-1), torch.ones(2, 2))
        True
    """
    shape = z.shape
    z = z.to(torch.promote_types(z.dtype, torch.float32)).reshape(*shape[:-1], groups, -1)
    if z.device.type == "cpu" and z.shape[-1] < _SHORT_GROUP_LANES:
        return torch.softmax(z.transpose(-1, -2), -2).transpose(-1, -2).reshape(shape)
    return torch.softmax(z, -1).reshape(shape)
