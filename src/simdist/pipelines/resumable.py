"""Training loops that survive a crash: atomic checkpoints of weights, optimisers and counters."""

from __future__ import annotations

import math
import zlib
from pathlib import Path
from typing import Callable

import torch
from tqdm import tqdm

from simdist.pipelines.experiment_log import log_metrics
from simdist.utils.checkpoint import load_checkpoint, save_atomic


def stage_seed(seed: int, name: str) -> int:
    """A seed for the stage or sub-stage ``name`` of a run seeded ``seed``.

    Seeding every (sub-)stage from its own name makes its random draws independent of
    what ran before it in the process, so a stage rerun after a crash draws what the
    uninterrupted run drew.

    Examples:
        >>> stage_seed(0, "pretrain") == stage_seed(0, "pretrain") != stage_seed(1, "pretrain")
        True
    """
    return (int(seed) * 1_000_003 + zlib.crc32(name.encode())) % (2**63 - 1)


def train_resumable(update: Callable, sample: Callable, updates: int, state: dict,
                    checkpoint: str | Path, every: int = 500, desc: str = "train",
                    progress: bool = True, seed: int | None = None, logger=None,
                    log_prefix: str | None = None) -> list[dict]:
    """Calls ``update(sample())`` ``updates`` times, checkpointing ``state`` atomically.

    ``state`` maps names to objects with ``state_dict``/``load_state_dict`` (modules,
    optimisers). If ``checkpoint`` exists, they are restored from it and training goes on
    from the recorded step, so a killed job rerun with the same command loses at most
    ``every`` updates. Each update's metrics (floats) are kept; a non-finite loss raises
    naming the step instead of silently training on NaN.

    Resumed equals uninterrupted (on the same device): each checkpoint also holds torch's
    global RNG state (what ``sample`` and ``update`` draw from), restored on resume; with
    ``seed``, a fresh start seeds that generator first (see :func:`stage_seed`), so the
    result does not depend on what ran earlier in the process either.

    With a TorchRL ``logger`` (see :mod:`simdist.pipelines.experiment_log`), every
    update's metrics are logged as ``<log_prefix or desc>/<metric>`` at its step.

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
        if "rng" in saved:
            torch.set_rng_state(saved["rng"])
    elif seed is not None:
        torch.manual_seed(seed)

    def save():
        save_atomic({"state": {n: o.state_dict() for n, o in state.items()},
                     "history": history, "rng": torch.get_rng_state()}, checkpoint)

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
        log_metrics(logger, log_prefix or desc, metrics, len(history))
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
