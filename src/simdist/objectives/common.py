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
