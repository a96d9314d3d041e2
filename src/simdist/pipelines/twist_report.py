"""Results of the TWIST recipe: a table shaped like the paper's Table I, IQM, and a plot.

``results`` maps task -> method -> ``{"returns": [every evaluation episode of every
seed], "seed_means": [...]}``; the method named :data:`ORACLE` (the state teacher) is
the normaliser.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from simdist.utils.atomic import atomic_path

ORACLE = "Oracle (state teacher)"


def interquartile_mean(values) -> float:
    """Mean of the middle 50% of ``values`` (rliable's IQM, robust to outlier episodes).

    Examples:
        >>> interquartile_mean([0, 1, 2, 3, 4, 5, 6, 100])
        3.5
    """
    x = np.sort(np.asarray(values, dtype=float))
    cut = int(np.floor(0.25 * len(x)))
    return float(x[cut:len(x) - cut].mean())


def summarise(results: dict) -> dict:
    """Per task and method: mean, std, mean normalised by the Oracle's mean return."""
    summary = {}
    for task, methods in results.items():
        if ORACLE not in methods:
            raise KeyError(f"{task}: no {ORACLE!r} entry to normalise by")
        oracle = float(np.mean(methods[ORACLE]["returns"]))
        summary[task] = {}
        for name, r in methods.items():
            returns = np.asarray(r["returns"], dtype=float)
            summary[task][name] = {
                "mean": float(returns.mean()), "std": float(returns.std()),
                "normalised": float(returns.mean() / oracle) if oracle else float("nan"),
                "normalised_iqm": interquartile_mean(returns / oracle) if oracle else
                float("nan"), "episodes": int(returns.size)}
    return summary


def format_table(results: dict) -> str:
    """Rows: methods; columns: tasks; cells ``mean +- std (x% of Oracle)``.

    Examples:
        >>> r = {"cartpole": {ORACLE: {"returns": [400, 600]}, "TWIST": {"returns": [400, 400]}}}
        >>> print(format_table(r))  # doctest: +NORMALIZE_WHITESPACE
        Return on held-out scenes (mean +- std over episodes and seeds; % of Oracle)
        method                          cartpole
        Oracle (state teacher)          500 +- 100 (100%)
        TWIST                           400 +- 0 (80%)
    """
    summary = summarise(results)
    tasks = list(summary)
    methods = list(dict.fromkeys(m for t in tasks for m in summary[t]))
    lines = ["Return on held-out scenes (mean +- std over episodes and seeds; % of Oracle)",
             (f"{'method':31s} " + " ".join(f"{t:24s}" for t in tasks)).rstrip()]
    for m in methods:
        cells = []
        for t in tasks:
            s = summary[t].get(m)
            cells.append("-" if s is None else
                         f"{s['mean']:.0f} +- {s['std']:.0f} ({100 * s['normalised']:.0f}%)")
        lines.append(f"{m:31s} " + " ".join(f"{c:24s}" for c in cells).rstrip())
    return "\n".join(lines)


def plot_results(results: dict, path: str | Path) -> None:
    """Bars of each method's Oracle-normalised mean return per task, with the IQM."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    summary = summarise(results)
    tasks = list(summary)
    methods = list(dict.fromkeys(m for t in tasks for m in summary[t]))
    fig, ax = plt.subplots(figsize=(2.5 + 1.6 * len(tasks) * len(methods) / 3, 4))
    width = 0.8 / len(methods)
    for i, m in enumerate(methods):
        xs = [j + (i - (len(methods) - 1) / 2) * width for j in range(len(tasks))]
        mean = [100 * summary[t][m]["normalised"] if m in summary[t] else 0 for t in tasks]
        iqm = [100 * summary[t][m]["normalised_iqm"] if m in summary[t] else 0 for t in tasks]
        ax.bar(xs, mean, width, label=m)
        ax.scatter(xs, iqm, color="k", marker="_", s=80, zorder=3)
    ax.axhline(100, color="k", lw=0.5)
    ax.set_xticks(range(len(tasks)), tasks)
    ax.set_ylabel("return on held-out scenes\n(% of Oracle; bar: mean, dash: IQM)")
    ax.set_title("TWIST: image students vs baselines")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    with atomic_path(path) as tmp:  # a crash mid-write keeps the previous plot
        fig.savefig(tmp, dpi=100)
    plt.close(fig)
