"""Scalar logging for training loops, through TorchRL's loggers, and the curves they make.

Recipes log every update's metrics under ``<output_dir>/logs`` with
``torchrl.record.loggers`` (CSV by default: one ``step,value`` file per scalar, appended
and flushed as it goes, so a long run can be watched and a crash loses nothing logged);
``"tensorboard"`` and ``"wandb"`` use TorchRL's loggers for those tools when they are
installed. :func:`plot_curves` turns the CSV files into one figure per run.
"""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

from torchrl.record.loggers import CSVLogger, Logger

from simdist.utils.atomic import atomic_path

LOGGERS = ("csv", "tensorboard", "wandb", "none")


def make_logger(kind: str, out_dir: str | Path, name: str = "logs") -> Logger | None:
    """A TorchRL logger writing under ``out_dir/name`` (``None`` for ``"none"``).

    Examples:
        >>> import tempfile
        >>> logger = make_logger("csv", tempfile.mkdtemp())
        >>> logger.log_scalar("pretrain/loss", 0.5, step=0)
        >>> make_logger("none", ".") is None
        True
    """
    if kind not in LOGGERS:
        raise ValueError(f"unknown logger {kind!r}; valid: {LOGGERS}")
    if kind == "none":
        return None
    if kind == "csv":
        return CSVLogger(exp_name=name, log_dir=str(out_dir))
    try:
        if kind == "tensorboard":
            from torchrl.record.loggers import TensorboardLogger
            return TensorboardLogger(exp_name=name, log_dir=str(out_dir))
        from torchrl.record.loggers import WandbLogger
        return WandbLogger(exp_name=name, save_dir=str(out_dir), offline=True)
    except ImportError as error:  # TorchRL imports the tool's package lazily
        raise ImportError(f"logger {kind!r} needs its package: {error}") from error


def log_metrics(logger: Logger | None, prefix: str, metrics: dict, step: int) -> None:
    """Logs each finite number in ``metrics`` as ``<prefix>/<key>`` at ``step``."""
    if logger is None:
        return
    for key, value in metrics.items():
        if isinstance(value, (int, float)) and math.isfinite(value):
            logger.log_scalar(f"{prefix}/{key}", float(value), step=step)


def read_csv_scalars(log_dir: str | Path) -> dict[str, tuple[list[int], list[float]]]:
    """Every scalar of a CSV log: name -> (steps, values), the last value kept per step
    (a resumed run re-logs the updates it redid after its last checkpoint)."""
    root = Path(log_dir) / "scalars"
    out = {}
    for path in sorted(root.rglob("*.csv")):
        by_step: dict[int, float] = {}
        for line in path.read_text().splitlines():
            step, _, value = line.partition(",")
            if step and value:
                by_step[int(float(step))] = float(value)
        steps = sorted(by_step)
        out[str(path.relative_to(root).with_suffix(""))] = (steps, [by_step[s] for s in steps])
    return out


def curves_figure(scalars: dict, smooth: int = 50):
    """The training-curves figure of :func:`plot_curves` from ``{name: (steps, values)}``.

    One row per stage (the name's prefix before its last ``/``); losses (``loss*``) and
    every other metric (returns, diagnostics) on separate axes of that row, so a return in
    the hundreds never flattens a loss; legends beside the axes, not over the lines;
    integer update ticks. Values are averaged over windows of ``smooth`` steps.

    Examples:
        >>> fig = curves_figure({"pretrain/loss_a": ([1, 2, 3], [3.0, 2.0, 1.0]),
        ...                      "pretrain/episode_return": ([1, 2, 3], [10.0, 50.0, 90.0])})
        >>> [ax.get_title() for ax in fig.axes]
        ['pretrain: losses', 'pretrain: other metrics']
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    groups = defaultdict(lambda: ({}, {}))
    for name, series in scalars.items():
        stage, _, metric = name.rpartition("/")
        groups[stage or "run"][0 if metric.startswith("loss") else 1][metric] = series
    rows = sorted(groups.items())
    columns = 2 if any(losses and others for _, (losses, others) in rows) else 1
    fig, axes = plt.subplots(len(rows), columns, figsize=(6.5 * columns, 2.6 * len(rows)),
                             squeeze=False)
    for row, (stage, kinds) in zip(axes, rows):
        panels = [(kind, metrics) for kind, metrics in zip(("losses", "other metrics"), kinds)
                  if metrics]
        for ax in row[len(panels):]:
            ax.set_visible(False)
        for ax, (kind, metrics) in zip(row, panels):
            for metric, (steps, values) in sorted(metrics.items()):
                k = max(1, min(smooth, len(values) // 20 or 1))
                xs = steps[k - 1::k] if k > 1 else steps
                ys = [sum(values[i:i + k]) / len(values[i:i + k])
                      for i in range(0, len(values), k)]
                ax.plot(xs[:len(ys)], ys[:len(xs)], label=metric)
            ax.set_title(f"{stage}: {kind}", fontsize=9)
            ax.set_xlabel("update")
            ax.xaxis.set_major_locator(MaxNLocator(integer=True))
            if all(v > 0 for _, (_, vals) in metrics.items() for v in vals):
                ax.set_yscale("log")
            ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0),
                      borderaxespad=0.0)
            ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def plot_curves(log_dir: str | Path, path: str | Path, smooth: int = 50) -> bool:
    """The training curves of a CSV log (:func:`curves_figure`) as a PNG at ``path``;
    returns whether anything was plotted."""
    scalars = read_csv_scalars(log_dir)
    if not scalars:
        return False
    import matplotlib.pyplot as plt

    fig = curves_figure(scalars, smooth)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format="png", bbox_inches="tight")
    plt.close(fig)
    return True
