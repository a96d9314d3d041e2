"""Slices of recorded episodes, drawn in proportion to how badly the model predicts them.

Prioritised experience replay (Schaul et al., 2016) over slice *starts*: a slice starting
at step ``i`` of an episode is drawn with probability ``P(i) = p_i^alpha / sum_j p_j^alpha``
and carries the importance weight ``w_i ~ (N P(i))^-beta`` (the largest in a batch is 1). In
SimDist's dynamics finetuning, ``p_i`` is the model's own latent-consistency error on the
slice, so the rare target transitions it predicts worst (a slip, a rollover) get more of
the updates than their share of the data.

TorchRL's :class:`~torchrl.data.PrioritizedSliceSampler` does this job with segment trees
from TorchRL's C++ extension, which does not load against the CPU torch wheel this
project pins (``SumSegmentTreeFp32 is not available``: the extension was built against
another torch). A few tens of thousands of starts (8 minutes of 50 Hz data) are cheap to
draw with :func:`torch.multinomial`, so this class does it in torch; the slices it returns
look like a ``SliceSampler``'s (``[slices, slice_len]``, ``is_init`` set on each slice's
first step, ``episode`` ids), plus ``slice_start`` and ``priority_weight``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator

import torch
from tensordict import TensorDict, TensorDictBase


class PrioritisedSlices:
    """Episode-safe slices of ``[episodes, steps]`` data, drawn by priority.

    Every start ``i`` whose slice fits inside its episode begins with priority 1 (so
    before :meth:`update_priority` the draw is uniform, as with TorchRL's ``SliceSampler``);
    :meth:`update_priority` sets the priorities of the starts a step trained on. Draws use
    torch's global generator, so a training loop that restores it on resume (e.g.
    :func:`~simdist.pipelines.resumable.train_resumable`) resumes exactly, with this
    object's :meth:`state_dict` in its checkpoint.

    Args:
        data: ``[episodes, steps]`` recordings of equal length (the recipe's target data).
        slice_len: steps per slice.
        batch_slices: slices per :meth:`sample`.
        alpha: how strongly priorities skew the draw (0: uniform).
        beta: importance-weight exponent (0: no correction; 1: full correction).
        eps: added to every priority, so no start is never drawn again.

    Examples:
        >>> data = TensorDict({"observation": torch.randn(3, 10, 2),
        ...                    "is_init": torch.zeros(3, 10, 1, dtype=torch.bool)}, [3, 10])
        >>> slices = PrioritisedSlices(data, slice_len=4, batch_slices=5, alpha=1.0, beta=0.5)
        >>> batch = slices.sample()
        >>> batch.shape, batch["is_init"][:, 0].all().item()
        (torch.Size([5, 4]), True)
        >>> slices.update_priority(batch["slice_start"][:, 0], torch.full((5,), 0.1))
    """

    def __init__(self, data: TensorDictBase, slice_len: int, batch_slices: int,
                 alpha: float = 0.6, beta: float = 0.4, eps: float = 1e-3):
        if data.batch_dims != 2:
            raise ValueError(f"data must be [episodes, steps], got batch_size "
                             f"{tuple(data.batch_size)}")
        episodes, steps = data.shape
        if not 1 <= slice_len <= steps:
            raise ValueError(f"slice_len must lie in [1, {steps}] (the episodes' length), "
                             f"got {slice_len}")
        if batch_slices < 1:
            raise ValueError(f"batch_slices must be >= 1, got {batch_slices}")
        for name, value in (("alpha", alpha), ("beta", beta), ("eps", eps)):
            if not (value >= 0 and math.isfinite(value)):
                raise ValueError(f"{name} must be a finite number >= 0, got {value}")
        if eps == 0:
            raise ValueError("eps must be > 0: a start with priority 0 is never drawn again")
        if "is_init" not in data.keys():
            raise KeyError("PrioritisedSlices needs an 'is_init' entry in the data (add "
                           "torchrl.envs.InitTracker() to the env that recorded it)")
        self.data, self.slice_len, self.batch_slices = data, slice_len, batch_slices
        self.alpha, self.beta, self.eps = alpha, beta, eps
        self.starts_per_episode = steps - slice_len + 1
        self.priority = torch.ones(episodes * self.starts_per_episode)

    def __len__(self) -> int:
        """The number of starts (slices that fit inside an episode)."""
        return self.priority.numel()

    def log_probabilities(self) -> torch.Tensor:
        """``log P(i)`` of every start, ``[len(self)]`` (in log space, so a large
        ``alpha`` cannot overflow ``p^alpha``)."""
        return torch.log_softmax(self.alpha * torch.log(self.priority.double() + self.eps), 0)

    def probabilities(self) -> torch.Tensor:
        """``P(i)`` of every start, ``[len(self)]``."""
        return self.log_probabilities().exp().float()

    def slices(self, starts: torch.Tensor) -> TensorDict:
        """The ``[len(starts), slice_len]`` slices beginning at ``starts`` (start ids).

        ``is_init`` is set on each slice's first step (OR-ed with the recorded flags), as
        TorchRL's ``SliceSampler`` does: the encoder sees no history from before the slice.
        """
        episode = torch.div(starts, self.starts_per_episode, rounding_mode="floor")
        step = starts % self.starts_per_episode
        steps = step[:, None] + torch.arange(self.slice_len)
        out = self.data[episode[:, None], steps].clone()
        is_init = out.get("is_init").clone()
        is_init[:, 0] = True
        out.set("is_init", is_init)
        out.set("episode", episode[:, None].expand(-1, self.slice_len).clone())
        out.set("slice_start", starts[:, None].expand(-1, self.slice_len).clone())
        return out

    def sample(self) -> TensorDict:
        """``batch_slices`` slices drawn by priority, with ``slice_start`` and the
        importance weight ``priority_weight`` (``[slices, slice_len, 1]``, the slice's
        weight on each of its steps; the batch's largest weight is 1)."""
        log_p = self.log_probabilities()
        starts = torch.multinomial(log_p.exp(), self.batch_slices, replacement=True)
        # w_i = (N P_i)^-beta, scaled so the batch's largest is 1 (the N cancels): a loss
        # that normalises by the weights' sum only sees their ratios, and a batch-wise
        # maximum cannot underflow the way the buffer-wide one does with a large alpha
        log_p = log_p[starts]
        weight = torch.exp(-self.beta * (log_p - log_p.min())).float()
        out = self.slices(starts)
        out.set("priority_weight", weight[:, None, None].expand(-1, self.slice_len, 1).clone())
        return out

    def update_priority(self, starts: torch.Tensor, priority: torch.Tensor) -> None:
        """Sets the priorities of the slices beginning at ``starts`` (a start drawn twice in
        one batch keeps the last value)."""
        priority = torch.as_tensor(priority, dtype=self.priority.dtype).reshape(-1)
        starts = torch.as_tensor(starts).reshape(-1)
        if priority.shape != starts.shape:
            raise ValueError(f"one priority per start: got {tuple(priority.shape)} "
                             f"priorities for {tuple(starts.shape)} starts")
        if not torch.isfinite(priority).all() or (priority < 0).any():
            raise ValueError("priorities must be finite and >= 0 (a non-finite model error "
                             "would be drawn forever, or never)")
        self.priority[starts] = priority

    def all_slices(self, chunk: int = 256) -> Iterator[TensorDict]:
        """Every slice once, in start order, ``chunk`` at a time (to measure them all)."""
        for first in range(0, len(self), chunk):
            yield self.slices(torch.arange(first, min(first + chunk, len(self))))

    def measure_all(self, error: Callable[[TensorDict], torch.Tensor], chunk: int = 256) -> None:
        """Sets every start's priority to ``error(slices)`` (one value per slice), e.g. the
        pretrained model's consistency error before finetuning starts."""
        for batch in self.all_slices(chunk):
            self.update_priority(batch["slice_start"][:, 0], error(batch))

    def state_dict(self) -> dict:
        return {"priority": self.priority.clone()}

    def load_state_dict(self, state: dict) -> None:
        priority = state["priority"]
        if priority.shape != self.priority.shape:
            raise ValueError(f"saved priorities cover {priority.numel()} starts, this data "
                             f"has {len(self)}: the checkpoint belongs to other data")
        self.priority = priority.clone()


def prioritised_update(step: Callable, slices: PrioritisedSlices) -> Callable:
    """Wraps a finetuning step (e.g. ``SimDistAgent.finetune_update``) so that every batch
    it trains on also sets its slices' priorities to their consistency errors.

    ``step(batch, slice_errors=True)`` must return ``(metrics, errors)`` with one error per
    slice; the wrapper returns the metrics, so it drops into
    :func:`~simdist.pipelines.resumable.train_resumable` as the plain step did.
    """

    def update(batch: TensorDictBase) -> dict:
        metrics, errors = step(batch, slice_errors=True)
        slices.update_priority(batch["slice_start"][:, 0], errors)
        return metrics

    return update
