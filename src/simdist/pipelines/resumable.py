"""Training loops that survive a crash: atomic checkpoints of weights, optimisers and counters."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Callable

import torch
from tqdm import tqdm

from simdist.utils.checkpoint import load_checkpoint, save_atomic


def train_resumable(update: Callable, sample: Callable, updates: int, state: dict,
                    checkpoint: str | Path, every: int = 500, desc: str = "train",
                    progress: bool = True) -> list[dict]:
    """Calls ``update(sample())`` ``updates`` times, checkpointing ``state`` atomically.

    ``state`` maps names to objects with ``state_dict``/``load_state_dict`` (modules,
    optimisers). If ``checkpoint`` exists, they are restored from it and training goes on
    from the recorded step, so a killed job rerun with the same command loses at most
    ``every`` updates. Each update's metrics (floats) are kept; a non-finite loss raises
    naming the step instead of silently training on NaN.

    Returns:
        The metrics of every update (restored ones included).

    Examples:
        >>> import tempfile
        >>> w = torch.nn.Linear(1, 1); opt = torch.optim.SGD(w.parameters(), lr=0.1)
        >>> def step(x):
        ...     loss = (w(x) - 2 * x).pow(2).mean(); opt.zero_grad(); loss.backward(); opt.step()
        ...     return {"loss": loss.item()}
        >>> ckpt = Path(tempfile.mkdtemp()) / "ckpt.pt"
        >>> hist = train_resumable(step, lambda: torch.randn(8, 1), 50, {"w": w, "opt": opt},
        ...                        ckpt, every=20, progress=False)
        >>> len(hist), hist[-1]["loss"] < hist[0]["loss"]
        (50, True)
        >>> len(train_resumable(step, lambda: torch.randn(8, 1), 50, {"w": w, "opt": opt},
        ...                     ckpt, progress=False))  # finished: nothing more to do
        50
    """
    checkpoint = Path(checkpoint)
    history: list[dict] = []
    if checkpoint.exists():
        saved = load_checkpoint(checkpoint)
        for name, obj in state.items():
            obj.load_state_dict(saved["state"][name])
        history = saved["history"]

    def save():
        save_atomic({"state": {n: o.state_dict() for n, o in state.items()},
                     "history": history}, checkpoint)

    # A finished run restored from its checkpoint shows no bar: nothing is trained.
    bar = tqdm(total=updates, initial=len(history), desc=desc,
               disable=not progress or len(history) >= updates)
    while len(history) < updates:
        metrics = update(sample())
        bad = [k for k, v in metrics.items() if k.startswith("loss") and not math.isfinite(v)]
        if bad:
            raise FloatingPointError(f"{desc}: non-finite {bad} at update {len(history)}; "
                                     f"last checkpoint kept at {checkpoint}")
        history.append(metrics)
        bar.update(1)
        if len(history) % every == 0 or len(history) == updates:
            save()
            bar.set_postfix({k: f"{v:.3g}" for k, v in metrics.items() if k.startswith("loss")})
    bar.close()
    if not checkpoint.exists():
        save()
    return history


def mean_metrics(history: list[dict], last: int = 100) -> dict[str, float]:
    """Mean of each metric over the last ``last`` updates (for result tables)."""
    tail = history[-last:]
    return {k: float(sum(h[k] for h in tail) / len(tail)) for k in tail[0]} if tail else {}


def weights(module: torch.nn.Module) -> dict:
    """A detached copy of a module's state dict (for saving or bit-exact comparisons)."""
    return {k: v.detach().clone() for k, v in module.state_dict().items()}
