"""Results of the TWIST recipe: a table shaped like the paper's Table I, IQM, and a plot.

``results`` maps task -> method -> ``{"returns": [every evaluation episode of every
seed], "seed_means": [...]}``; the method named :data:`ORACLE` (the state teacher) is
the normaliser.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from simdist.pipelines.statistics import summarise_groups
from simdist.utils.atomic import atomic_path

ORACLE = "Oracle (state teacher)"


def summarise(results: dict) -> dict:
    """Per task and method: mean, std, IQM and a bootstrap 95% CI of the return and of
    the return normalised by the Oracle's mean (:func:`~simdist.pipelines.statistics.
    summarise_groups`: SciPy's trimmed mean and bootstrap, stratified by seed when a
    method lists ``"seed_returns"``, one list of episode returns per seed).

    Examples:
        >>> r = {"cartpole": {ORACLE: {"returns": [400, 600]},
        ...                   "TWIST": {"returns": [300, 400, 500], "seed_returns": [[300], [400, 500]]}}}
        >>> s = summarise(r)["cartpole"]["TWIST"]
        >>> s["mean"], round(s["normalised"], 3), s["seeds"], round(s["std_over_seeds"], 1)
        (400.0, 0.8, 2, 75.0)
        >>> s["normalised_ci_low"] <= s["normalised"] <= s["normalised_ci_high"]
        True
    """
    summary = {}
    for task, methods in results.items():
        if ORACLE not in methods:
            raise KeyError(f"{task}: no {ORACLE!r} entry to normalise by")
        oracle = float(np.mean(methods[ORACLE]["returns"]))
        summary[task] = {}
        for name, r in methods.items():
            groups = [np.asarray(g, dtype=float) for g in r.get("seed_returns") or
                      [r["returns"]]]
            raw = summarise_groups(groups)
            entry = {"mean": raw["mean"], "std": raw["std"], "iqm": raw["iqm"],
                     "ci_low": raw["ci_low"], "ci_high": raw["ci_high"],
                     "episodes": raw["n"], "seeds": len(groups),
                     "std_over_seeds": raw["std_over_seeds"]}
            if oracle:
                norm = summarise_groups([g / oracle for g in groups])
                entry.update({"normalised": norm["mean"], "normalised_iqm": norm["iqm"],
                              "normalised_ci_low": norm["ci_low"],
                              "normalised_ci_high": norm["ci_high"]})
                if "ci_seeds_low" in norm:  # several seeds: the interval resampling them
                    entry["normalised_ci_seeds"] = [norm["ci_seeds_low"], norm["ci_seeds_high"]]
            else:
                entry.update(dict.fromkeys(("normalised", "normalised_iqm",
                                            "normalised_ci_low", "normalised_ci_high"),
                                           float("nan")))
            summary[task][name] = entry
    return summary


def format_table(results: dict) -> str:
    """Rows: methods; columns: tasks; cells ``mean +- std (x% [CI] IQM y%)`` of the Oracle.

    Examples:
        >>> r = {"cartpole": {ORACLE: {"returns": [400, 600]}, "TWIST": {"returns": [400, 400]}}}
        >>> print(format_table(r))  # doctest: +NORMALIZE_WHITESPACE
        Return on held-out scenes: mean +- std over episodes and seeds; % of Oracle: mean [bootstrap 95% CI] IQM
        method                          cartpole
        Oracle (state teacher)          500 +- 100 (100% [80, 120] IQM 100%)
        TWIST                           400 +- 0 (80% [80, 80] IQM 80%)
    """
    summary = summarise(results)
    tasks = list(summary)
    methods = list(dict.fromkeys(m for t in tasks for m in summary[t]))
    lines = ["Return on held-out scenes: mean +- std over episodes and seeds; % of Oracle: "
             "mean [bootstrap 95% CI] IQM",
             (f"{'method':31s} " + " ".join(f"{t:40s}" for t in tasks)).rstrip()]
    for m in methods:
        cells = []
        for t in tasks:
            s = summary[t].get(m)
            cells.append("-" if s is None else
                         f"{s['mean']:.0f} +- {s['std']:.0f} ({100 * s['normalised']:.0f}% "
                         f"[{100 * s['normalised_ci_low']:.0f}, "
                         f"{100 * s['normalised_ci_high']:.0f}] "
                         f"IQM {100 * s['normalised_iqm']:.0f}%)")
        lines.append(f"{m:31s} " + " ".join(f"{c:40s}" for c in cells).rstrip())
    return "\n".join(lines)


def plot_results(results: dict, path: str | Path) -> None:
    """Bars of each method's Oracle-normalised mean return per task, with its bootstrap
    95% CI and the IQM."""
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
        low = [100 * summary[t][m]["normalised_ci_low"] if m in summary[t] else 0 for t in tasks]
        high = [100 * summary[t][m]["normalised_ci_high"] if m in summary[t] else 0
                for t in tasks]
        ax.bar(xs, mean, width, label=m, yerr=[np.subtract(mean, low), np.subtract(high, mean)],
               capsize=2, error_kw={"lw": 0.8})
        ax.scatter(xs, iqm, color="k", marker="_", s=80, zorder=3)
    ax.axhline(100, color="k", lw=0.5)
    ax.set_xticks(range(len(tasks)), tasks)
    ax.set_ylabel("return on held-out scenes\n(% of Oracle; bar: mean, 95% CI; dash: IQM)")
    ax.set_title("TWIST: image students vs baselines")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    with atomic_path(path) as tmp:  # a crash mid-write keeps the previous plot
        fig.savefig(tmp, dpi=100)
    plt.close(fig)
