"""Shared plumbing for simdist losses: key reading with clear errors, finiteness checks."""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from torch import nn
from torchrl.objectives import LossModule


class MissingKeyError(KeyError):
    """A required TensorDict key is absent (message printed unquoted, unlike KeyError).

    Raised by :meth:`SimdistLoss.read`, naming the key, the loss and how to remap it.

    Examples:
        >>> from simdist.modules import DreamerWorldModel
        >>> from simdist.objectives import DreamerWorldModelLoss
        >>> loss = DreamerWorldModelLoss(DreamerWorldModel.teacher(3, 1, size="tiny"))
        >>> try:
        ...     loss(TensorDict({}, [2, 4]))
        ... except MissingKeyError as err:
        ...     print(isinstance(err, KeyError), str(err).split(";")[0])
        True DreamerWorldModelLoss: input has no ('next', 'state') for 'observation'
    """

    def __str__(self) -> str:
        return str(self.args[0])


class SimdistLoss(LossModule):
    """A TorchRL ``LossModule`` that names what it trains and checks its inputs.

    Subclasses define ``_AcceptedKeys`` (remappable with ``set_keys``) and
    :meth:`trainable_parameters`; inputs are read with :meth:`read`, which fails with the
    missing key's name (and how to remap it) or on NaN/inf; :meth:`finish` checks every
    ``loss_*`` term is finite before returning.

    Args:
        check_inputs: verify inputs are finite (one host sync per key; disable for speed
            once a pipeline is trusted).

    Examples:
        >>> from simdist.modules import DreamerWorldModel
        >>> from simdist.objectives import DreamerWorldModelLoss
        >>> loss = DreamerWorldModelLoss(DreamerWorldModel.teacher(3, 1, size="tiny"))
        >>> loss.set_keys(observation="obs")
        >>> loss.read(TensorDict({"obs": torch.full((2, 3), float("nan"))}, [2]), "observation")
        Traceback (most recent call last):
        ...
        ValueError: DreamerWorldModelLoss: 'obs' contains NaN or inf
    """

    def __init__(self, check_inputs: bool = True):
        super().__init__()
        self.check_inputs = check_inputs

    def trainable_parameters(self) -> list[nn.Parameter]:
        """The parameters this loss is meant to update (give these to the optimiser)."""
        raise NotImplementedError

    def read(self, td: TensorDictBase, name: str) -> torch.Tensor:
        key = getattr(self.tensor_keys, name)
        value = td.get(key, None)
        if value is None:
            hint = " (add torchrl.envs.InitTracker() to the env)" if name == "is_init" else ""
            raise MissingKeyError(f"{type(self).__name__}: input has no {key!r} for {name!r}{hint}; "
                           f"remap with set_keys({name}=...). Present keys: "
                           f"{sorted(map(str, td.keys(True, True)))}")
        if self.check_inputs and value.is_floating_point() and not torch.isfinite(value).all():
            raise ValueError(f"{type(self).__name__}: {key!r} contains NaN or inf")
        return value

    def read_scalar(self, td: TensorDictBase, name: str, lead) -> torch.Tensor:
        """A per-step scalar (reward, value target) of shape ``[*lead, 1]``.

        Without this check a ``[B, T]`` reward broadcasts against ``[B, T, 1]``
        predictions into a ``[B, T, T]`` error: a wrong loss, or an anonymous shape error.
        """
        value = self.read(td, name)
        check_per_step_scalar(type(self).__name__, getattr(self.tensor_keys, name), value, lead)
        return value

    def read_pixels(self, td: TensorDictBase, name: str) -> torch.Tensor:
        """Images: uint8 in ``[0, 255]``, or float already in ``[-0.5, 0.5]`` (see
        :func:`check_pixels`; the range check is skipped with ``check_inputs=False``)."""
        value = self.read(td, name)
        check_pixels(type(self).__name__, getattr(self.tensor_keys, name), value,
                     check_range=self.check_inputs)
        return value

    def read_flag(self, td: TensorDictBase, name: str, shape) -> torch.Tensor:
        """A boolean ``[B, T]`` flag (accepts a trailing singleton dimension)."""
        value = self.read(td, name)
        if value.shape != tuple(shape):
            value = value.reshape(shape)
        return value.bool()

    @staticmethod
    def finish(td: TensorDict) -> TensorDict:
        for key, value in td.items():
            if key.startswith("loss_") and not torch.isfinite(value).all():
                raise FloatingPointError(f"loss term {key!r} is not finite ({value}); check "
                                         "learning rate, inputs and model outputs")
        return td


def sequence_batch(td: TensorDictBase) -> tuple[int, int]:
    """``(B, T)`` of a ``[B, T]`` slice batch, with a clear error otherwise."""
    if td.batch_dims != 2:
        raise ValueError(f"expected a [batch, time] TensorDict of slices, got batch_size "
                         f"{tuple(td.batch_size)} (sample with a SliceSampler and reshape)")
    return tuple(td.batch_size)


def check_per_step_scalar(owner: str, key, value: torch.Tensor, lead) -> None:
    """Raises unless ``value`` is ``[*lead, 1]``: one scalar per step, with the trailing 1.

    Examples:
        >>> check_per_step_scalar("MyLoss", "reward", torch.zeros(2, 5), (2, 5))
        ... # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        ValueError: MyLoss: 'reward' must have shape (2, 5, 1) ..., got (2, 5): add the ...
    """
    lead = tuple(lead)
    if tuple(value.shape) == (*lead, 1):
        return
    hint = ""
    if tuple(value.shape) == lead:
        name = key[-1] if isinstance(key, tuple) else key
        hint = f": add the trailing 1 ({name}.unsqueeze(-1)); TorchRL envs write it"
    raise ValueError(f"{owner}: {key!r} must have shape {(*lead, 1)} (one scalar per step), "
                     f"got {tuple(value.shape)}{hint}")


def check_pixels(owner: str, key, pixels: torch.Tensor, check_range: bool = True) -> None:
    """Raises unless ``pixels`` follow the encoders' convention.

    ``uint8`` images in ``[0, 255]`` (what the envs render) are scaled by the models; a
    floating-point image is taken as already scaled to ``[-0.5, 0.5]``
    (:func:`~simdist.modules.heads.pixels_to_target`), so a float image in ``[0, 255]``
    or ``[0, 1]`` would be fed unscaled or shifted. Other integer types are refused for the
    same reason. ``check_range`` (one host sync) can be turned off for speed.

    Examples:
        >>> check_pixels("MyLoss", "pixels", torch.zeros(2, 8, 8, 3, dtype=torch.uint8))
        >>> check_pixels("MyLoss", "pixels", torch.full((2, 8, 8, 3), 255.0))
        ... # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        ValueError: MyLoss: float 'pixels' must lie in [-0.5, 0.5] ..., got values in [255, 255]...
    """
    if pixels.dtype == torch.uint8:
        return
    if not pixels.is_floating_point():
        raise TypeError(f"{owner}: {key!r} must be uint8 images (or floats in [-0.5, 0.5]), "
                        f"got {pixels.dtype}")
    if not check_range or pixels.numel() == 0 or pixels.device.type == "meta":
        return
    low, high = torch.aminmax(pixels.detach())
    low, high = low.item(), high.item()
    if low < -0.5 - _PIXEL_SLACK or high > 0.5 + _PIXEL_SLACK:
        raise ValueError(f"{owner}: float {key!r} must lie in [-0.5, 0.5] (uint8 / 255 - 0.5), "
                         f"got values in [{low:g}, {high:g}]; pass the uint8 images, or scale "
                         "them with simdist.modules.heads.pixels_to_target")


# Rounding slack for float images computed as uint8 / 255 - 0.5 (and then e.g. resized).
_PIXEL_SLACK = 1e-3
