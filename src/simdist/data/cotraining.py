"""Finetuning batches that mix target slices with slices of the simulation dataset."""

from __future__ import annotations

from typing import Callable, Sequence

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey

SliceSource = Callable[[], TensorDictBase]  # returns ``[slices, slice_len]``


class CoTrainingSlices:
    """Each call returns the target source's slices followed by the simulation source's.

    Co-training keeps part of every finetuning batch on the pretraining data, so the
    finetuned part stays fitted where the few minutes of target data say nothing, while
    the target slices move it where they do. Only ``keys`` are kept (the two sources
    record different extras: the dataset has value labels, target data has next
    observations); a ``from_simulation`` flag (``[slices, slice_len, 1]``) marks the
    simulation slices.

    Args:
        target: returns ``[n_target, slice_len]`` target slices.
        simulation: returns ``[n_sim, slice_len]`` slices of the simulation dataset.
        keys: the entries the finetuning loss reads (each must be in both sources).

    Examples:
        >>> from tensordict import TensorDict
        >>> src = lambda n, v: (lambda: TensorDict({"observation": torch.full((n, 4, 2), v),
        ...     "extra": torch.zeros(n, 4)}, [n, 4]))
        >>> mix = CoTrainingSlices(src(3, 1.0), src(1, 2.0), keys=["observation"])
        >>> batch = mix()
        >>> batch.shape, batch["from_simulation"][:, 0, 0].tolist()
        (torch.Size([4, 4]), [False, False, False, True])
    """

    FLAG = "from_simulation"

    def __init__(self, target: SliceSource, simulation: SliceSource, keys: Sequence[NestedKey]):
        if not keys:
            raise ValueError("keys must name the entries the finetuning loss reads")
        self.target, self.simulation, self.keys = target, simulation, list(keys)

    def _take(self, source: SliceSource, name: str) -> TensorDictBase:
        td = source()
        if td.batch_dims != 2:
            raise ValueError(f"the {name} source must return [slices, slice_len] slices, "
                             f"got batch shape {tuple(td.batch_size)}")
        missing = [k for k in self.keys if k not in td.keys(include_nested=True)]
        if missing:
            held = sorted(map(str, td.keys(include_nested=True, leaves_only=True)))
            raise KeyError(f"the {name} slices lack {', '.join(map(str, missing))} (they hold "
                           f"{', '.join(held)})")
        return td.select(*self.keys)

    def __call__(self) -> TensorDictBase:
        target, sim = self._take(self.target, "target"), self._take(self.simulation, "simulation")
        if target.shape[1] != sim.shape[1]:
            raise ValueError(f"slice lengths differ: target {target.shape[1]}, "
                             f"simulation {sim.shape[1]}")
        for key in self.keys:
            a, b = target.get(key), sim.get(key)
            if a.shape[2:] != b.shape[2:] or a.dtype != b.dtype:
                raise ValueError(f"{key!r} differs between target {tuple(a.shape[2:])} "
                                 f"{a.dtype} and simulation {tuple(b.shape[2:])} {b.dtype}")
        target.set(self.FLAG, torch.zeros(*target.shape, 1, dtype=torch.bool))
        sim.set(self.FLAG, torch.ones(*sim.shape, 1, dtype=torch.bool))
        return torch.cat([target, sim], 0)
