"""Results table and plot for the SimDist transfer curves (forward progress vs target data).

``results`` maps ``"minutes"`` to the data budgets and each method's name to one
:func:`~simdist.pipelines.progress_stats` dict per budget. The keys of
:data:`REFERENCES` hold one figure each, the same at every budget: the pretrained
planner in simulation (the level finetuning should approach), and in the target the
policy prior alone and the planner with the simulator as its dynamics (the ceiling of
finetuning the dynamics alone).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from simdist.pipelines.statistics import summarise, summarise_groups
from simdist.utils.atomic import atomic_path


#: Results keys holding one figure each (not one per budget), and their table rows' names.
REFERENCES = {
    "planner_in_sim": "(pretrained planner in sim)",
    "prior_alone": "(policy prior alone)",
    "simulator_ceiling": "(simulator as dynamics)",
}


def _methods(results: dict) -> list[str]:
    return [k for k in results if k != "minutes" and k not in REFERENCES]


def _rows(results: dict) -> list[tuple[str, float | None, dict]]:
    """``(method, minutes, point)`` per table row; the references last, without minutes."""
    rows = [(name, minutes, r) for name in _methods(results)
            for minutes, r in zip(results["minutes"], results[name])]
    rows += [(label, None, results[key]) for key, label in REFERENCES.items()
             if key in results]
    return rows


def _budget_cell(minutes: float | None) -> str:
    """The 12-character "target data" cell of a row ("-" for the sim reference)."""
    return f"{minutes:8.2f} min" if minutes is not None else f"{'-':>12s}"


def _pooled_over_seeds(results: dict) -> bool:
    """Whether the points carry the interval that resamples seeds (several seeds pooled)."""
    return any("ci_fraction_seeds" in r for _, _, r in _rows(results))


def format_table(results: dict, target: str) -> str:
    """A plain-text table: one row per method and data budget.

    Examples:
        >>> s = {"mean_m": 1.0, "std_m": 0.1, "mean_fraction": 0.5, "std_fraction": 0.05,
        ...      "iqm_fraction": 0.52, "ci_fraction": [0.45, 0.55]}
        >>> print(format_table({"minutes": [0.0], "m": [s]}, "ice"))  # doctest: +NORMALIZE_WHITESPACE
        Forward progress in ice, % of the commanded distance over episodes (mean, IQM,
        bootstrap 95% CI of the mean)
        method    target data  progress (m)   mean    IQM    95% CI
        m            0.00 min          1.00    50%    52% [  45,   55]%
    """
    lines = [f"Forward progress in {target}, % of the commanded distance over episodes "
             "(mean, IQM, bootstrap 95% CI of the mean)",
             f"{'method':33s} {'target data':>12s} {'progress (m)':>13s} {'mean':>6s} "
             f"{'IQM':>6s} {'95% CI':>13s}"]
    rows = _rows(results)
    # several seeds: the interval that also resamples the seeds (interval_over_seeds)
    over_seeds = _pooled_over_seeds(results)
    if over_seeds:
        lines[0] += "; the last column also resamples the seeds"
        lines[1] += f" {'CI over seeds':>15s}"
    for name, minutes, r in rows:
        when = _budget_cell(minutes)
        iqm = r.get("iqm_fraction", r["mean_fraction"])
        low, high = r.get("ci_fraction", [r["mean_fraction"]] * 2)
        line = (f"{name:33s} {when} {r['mean_m']:13.2f} {100 * r['mean_fraction']:5.0f}% "
                f"{100 * iqm:5.0f}% [{100 * low:4.0f}, {100 * high:4.0f}]%")
        if over_seeds:
            low, high = r.get("ci_fraction_seeds", [r["mean_fraction"]] * 2)
            line += f"   [{100 * low:4.0f}, {100 * high:4.0f}]%"
        lines.append(line)
    return "\n".join(lines)


def format_by_command(results: dict, target: str) -> str | None:
    """Mean % of the commanded distance per commanded speed: one row per method and budget.

    The pooled mean can hide one speed that fails (on a slippery slope the slowest
    command slides back while the faster ones climb), so the recipe prints this beside
    the main table. ``None`` when some point lacks the per-episode ``command_mps``
    (records written before it was kept).

    Examples:
        >>> p = {"fraction": [0.5, 0.7, -0.2, 0.0], "command_mps": [0.5, 0.5, 0.25, 0.25]}
        >>> print(format_by_command({"minutes": [0.0], "m": [p]}, "ice"))  # doctest: +NORMALIZE_WHITESPACE
        Forward progress in ice by commanded speed, % of the commanded distance (mean
        [bootstrap 95% CI over that speed's episodes], episodes)
        method    target data           0.25 m/s            0.5 m/s
        m            0.00 min  -10% [ -20,    0] (2)  60% [  50,   70] (2)
    """
    rows = _rows(results)
    if not rows or any("command_mps" not in r for _, _, r in rows):
        return None
    speeds = sorted({round(c, 6) for _, _, r in rows for c in r["command_mps"]})
    lines = [f"Forward progress in {target} by commanded speed, % of the commanded distance "
             "(mean [bootstrap 95% CI over that speed's episodes], episodes)",
             f"{'method':33s} {'target data':>12s}"
             + "".join(f" {f'{s:g} m/s':>24s}" for s in speeds)]
    for name, minutes, r in rows:
        when = _budget_cell(minutes)
        fraction = np.asarray(r["fraction"], dtype=np.float64)
        command = np.round(np.asarray(r["command_mps"], dtype=np.float64), 6)
        cells = []
        for speed in speeds:
            chosen = fraction[command == speed]
            if chosen.size == 0:
                cells.append(f" {'-':>24s}")
                continue
            s = summarise(chosen)
            cells.append(f" {100 * s['mean']:5.0f}% [{100 * s['ci_low']:4.0f}, "
                         f"{100 * s['ci_high']:4.0f}] ({s['n']})".rjust(25))
        lines.append(f"{name:33s} {when}" + "".join(cells))
    return "\n".join(lines)


def format_tracking_error(results: dict, target: str) -> str:
    """How far each method's episodes end from the commanded distance, in either direction.

    The main table's mean fraction rewards overshooting: an episode that walks 150% of the
    commanded distance counts more than one that walks 100%, although it follows the
    command worse. This table reports the tracking error ``|1 - fraction|`` per episode
    (mean [bootstrap 95% CI over episodes]; lower is better) and the share of episodes
    that overshoot by more than 10%.

    Examples:
        >>> p = {"fraction": [0.9, 1.1, 1.5, 0.5]}
        >>> print(format_tracking_error({"minutes": [0.0], "m": [p]}, "ice"))  # doctest: +NORMALIZE_WHITESPACE
        Command tracking in ice: |1 - fraction of the commanded distance| per episode (mean
        [bootstrap 95% CI over episodes], lower is better) and episodes beyond 110%
        method    target data   tracking error   beyond 110%
        m            0.00 min  30% [  10,   50]           25%
    """
    lines = [f"Command tracking in {target}: |1 - fraction of the commanded distance| per "
             "episode (mean [bootstrap 95% CI over episodes], lower is better) and episodes "
             "beyond 110%",
             f"{'method':33s} {'target data':>12s} {'tracking error':>16s} {'beyond 110%':>13s}"]
    for name, minutes, r in _rows(results):
        when = _budget_cell(minutes)
        fraction = np.asarray(r["fraction"], dtype=np.float64)
        s = summarise(np.abs(1.0 - fraction))
        lines.append(f"{name:33s} {when} {100 * s['mean']:3.0f}% [{100 * s['ci_low']:4.0f}, "
                     f"{100 * s['ci_high']:4.0f}] {100 * np.mean(fraction > 1.1):12.0f}%")
    return "\n".join(lines)


def _seed_groups(point: dict) -> list[np.ndarray]:
    """A point's per-episode fractions split by seed (one group for a single run)."""
    fraction = np.asarray(point["fraction"], dtype=np.float64)
    sizes = point.get("seed_episodes")
    if not sizes or sum(sizes) != fraction.size:
        return [fraction]
    return np.split(fraction, np.cumsum(sizes)[:-1])


def _same_worlds(a: dict, b: dict) -> bool:
    """Whether two points hold one episode each of the same worlds, in the same order."""
    if len(a["fraction"]) != len(b["fraction"]):
        return False
    if "command_mps" in a and "command_mps" in b:  # the drawn speeds must agree too
        return np.allclose(a["command_mps"], b["command_mps"])
    return True


def format_paired_differences(results: dict, target: str, reference: str) -> str | None:
    """``reference`` minus each method, paired by episode, in points of the commanded distance.

    Every method is evaluated on the same worlds (same initial states and commanded
    speeds), so the difference of two methods is best measured episode by episode: the
    world-to-world spread that widens each method's own interval cancels. One row per
    comparison: the reference at each budget minus its own first point (what the target
    data added) and minus every other method at the same budget; mean [bootstrap 95% CI]
    of the per-episode differences, stratified by seed when several seeds were pooled.
    A difference whose interval excludes 0 is one the data support. ``None`` when some
    pair of points does not hold the same worlds (their episode counts or speeds differ)
    or ``reference`` is not a method of ``results``.

    Examples:
        >>> p = lambda f: {"fraction": f}
        >>> r = {"minutes": [0.0, 8.0], "mine": [p([0.2, 0.4]), p([0.5, 0.9])],
        ...      "other": [p([0.2, 0.4]), p([0.3, 0.5])]}
        >>> print(format_paired_differences(r, "ice", "mine"))  # doctest: +NORMALIZE_WHITESPACE
        Paired by episode in ice: mine minus each method, points of the commanded distance
        (mean [bootstrap 95% CI of the per-episode differences])
        minus (at the same budget)            0.00 min          8.00 min
        its own 0.00 min point                   -      +40 [ +30,  +50]
        other                          +0 [  +0,   +0]  +30 [ +20,  +40]
    """
    if reference not in _methods(results):
        return None
    ref, minutes = results[reference], results["minutes"]
    comparisons = [(f"its own {minutes[0]:.2f} min point", [ref[0]] * len(ref))]
    comparisons += [(name, results[name]) for name in _methods(results) if name != reference]
    if not all(_same_worlds(a, b) for _, others in comparisons for a, b in zip(ref, others)):
        return None
    stratified = len(_seed_groups(ref[0])) > 1
    lines = [f"Paired by episode in {target}: {reference} minus each method, points of the "
             "commanded distance (mean [bootstrap 95% CI of the per-episode differences"
             + (", stratified by seed" if stratified else "") + "])",
             f"{'minus (at the same budget)':33s}"
             + "".join(f" {_budget_cell(m):>17s}" for m in minutes)]
    for row, (label, others) in enumerate(comparisons):
        cells = []
        for i, (mine, other) in enumerate(zip(ref, others)):
            if row == 0 and i == 0:  # the first point against itself: nothing to compare
                cells.append(f" {'-':>17s}")
                continue
            mine_groups, other_groups = _seed_groups(mine), _seed_groups(other)
            if [len(g) for g in mine_groups] != [len(g) for g in other_groups]:
                # split by seed differently (a record without episode counts): pool both
                mine_groups = [np.concatenate(mine_groups)]
                other_groups = [np.concatenate(other_groups)]
            groups = [100 * (a - b) for a, b in zip(mine_groups, other_groups)]
            s = summarise_groups(groups)
            cells.append(f" {s['mean']:+4.0f} [{s['ci_low']:+5.0f}, {s['ci_high']:+5.0f}]")
        lines.append(f"{label:33s}" + "".join(cells))
    return "\n".join(lines)


def format_upside_down(results: dict, target: str) -> str | None:
    """Evaluation episodes that had the robot on its back at some step, per commanded
    speed: one row per method and budget. ``None`` when some point lacks the per-episode
    ``command_mps`` or when no point has ``upside_down`` (records written before they
    were kept); a point without ``upside_down`` among others that have it (a run that
    reused an older stage record) prints ``n/a`` cells.

    A roll is the failure no later step repairs, so a method's mean fraction of the
    commanded distance can hide whether it fails by walking slowly or by falling over.

    Examples:
        >>> p = {"fraction": [0.5, -0.2, 0.0], "command_mps": [0.5, 0.25, 0.25],
        ...      "upside_down": [False, True, False]}
        >>> print(format_upside_down({"minutes": [0.0], "m": [p]}, "ice"))  # doctest: +NORMALIZE_WHITESPACE
        Episodes on their back at some step in ice, by commanded speed (on their back / episodes)
        method    target data   0.25 m/s    0.5 m/s
        m            0.00 min        1/2        0/1
    """
    rows = _rows(results)
    if (not rows or any("command_mps" not in r for _, _, r in rows)
            or not any("upside_down" in r for _, _, r in rows)):
        return None
    speeds = sorted({round(c, 6) for _, _, r in rows for c in r["command_mps"]})
    lines = [f"Episodes on their back at some step in {target}, by commanded speed (on their "
             "back / episodes)",
             f"{'method':33s} {'target data':>12s}" + "".join(f" {f'{v:g} m/s':>10s}" for v in speeds)]
    for name, minutes, r in rows:
        if "upside_down" not in r:
            lines.append(f"{name:33s} {_budget_cell(minutes)}"
                         + "".join(f" {'n/a':>10s}" for _ in speeds))
            continue
        flipped = np.asarray(r["upside_down"], dtype=bool)
        command = np.round(np.asarray(r["command_mps"], dtype=np.float64), 6)
        cells = [f"{int(flipped[command == v].sum())}/{int((command == v).sum())}"
                 for v in speeds]
        lines.append(f"{name:33s} {_budget_cell(minutes)}" + "".join(f" {c:>10s}" for c in cells))
    return "\n".join(lines)


def print_table(results: dict, target: str, reference: str | None = None) -> None:
    """Prints the results table, its split by commanded speed, the tracking table and,
    given ``reference`` (a method's name), that method's paired differences."""
    print("\n" + format_table(results, target))
    by_command = format_by_command(results, target)
    if by_command is not None:
        print("\n" + by_command)
    upside_down = format_upside_down(results, target)
    if upside_down is not None:
        print("\n" + upside_down)
    print("\n" + format_tracking_error(results, target))
    paired = format_paired_differences(results, target, reference) if reference else None
    if paired is not None:
        print("\n" + paired)


def plot_results(results: dict, target: str, path: str | Path) -> None:
    """Saves a PNG of forward progress (% of commanded) against minutes of target data."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4))
    minutes = results["minutes"]
    for name in _methods(results):
        mean = [100 * r["mean_fraction"] for r in results[name]]
        # the band over seeds and episodes when several seeds were pooled
        ci = [r.get("ci_fraction_seeds", r.get("ci_fraction", [r["mean_fraction"]] * 2))
              for r in results[name]]
        style = "--" if name.startswith("expert") else "-o"
        line, = ax.plot(minutes, mean, style, label=name)
        ax.fill_between(minutes, [100 * c[0] for c in ci], [100 * c[1] for c in ci],
                        color=line.get_color(), alpha=0.15)
    for key, style in (("planner_in_sim", ":"), ("simulator_ceiling", "--"),
                       ("prior_alone", "-.")):
        if key in results:
            ax.axhline(100 * results[key]["mean_fraction"], color="gray", lw=1, ls=style,
                       label=REFERENCES[key].strip("()"))
    ax.axhline(100, color="k", lw=0.5)
    ax.set_xlabel(f"minutes of 50 Hz data collected in {target}")
    ax.set_ylabel("forward progress, % of commanded\n(mean, band: bootstrap 95% CI"
                  + (" over seeds)" if _pooled_over_seeds(results) else ")"))
    ax.set_title(f"SimDist transfer to {target}")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    with atomic_path(path) as tmp:  # a crash mid-write keeps the previous plot
        fig.savefig(tmp, dpi=100)
    plt.close(fig)


def _aggregate_point(points: list[dict]) -> dict:
    fractions = [p["fraction"] for p in points]
    metres = np.concatenate([np.asarray(p["progress_m"], dtype=np.float64) for p in points])
    s = summarise_groups(fractions)
    # the per-episode speeds travel with the fractions when every seed recorded them
    commands = {key: [c for p in points for c in p[key]]
                for key in ("command_mps", "upside_down") if all(key in p for p in points)}
    return {"fraction": [f for p in points for f in p["fraction"]], "progress_m": metres.tolist(),
            **commands, "mean_m": float(metres.mean()), "std_m": float(metres.std()),
            "mean_fraction": s["mean"], "std_fraction": s["std"], "iqm_fraction": s["iqm"],
            "ci_fraction": [s["ci_low"], s["ci_high"]], "seed_means": s["group_means"],
            # episodes per seed, so paired differences can be stratified by seed later
            "seed_episodes": [len(f) for f in fractions],
            **({"ci_fraction_seeds": [s["ci_seeds_low"], s["ci_seeds_high"]]}
               if "ci_seeds_low" in s else {}),
            "std_over_seeds": s["std_over_seeds"],
            "return": float(np.mean([p["return"] for p in points]))}


def aggregate_seeds(per_seed: list[dict]) -> dict:
    """One results dict from several seeds' (same methods and budgets): every point pools
    the seeds' episodes (mean, IQM, CI stratified by seed) and keeps each seed's mean.

    Examples:
        >>> point = lambda f: {"fraction": f, "progress_m": f, "return": 1.0}
        >>> runs = [{"minutes": [0.0], "m": [point([0.1, 0.3])]},
        ...         {"minutes": [0.0], "m": [point([0.5, 0.7])]}]
        >>> agg = aggregate_seeds(runs)
        >>> round(agg["m"][0]["mean_fraction"], 2), [round(m, 2) for m in agg["m"][0]["seed_means"]]
        (0.4, [0.2, 0.6])
    """
    first = per_seed[0]
    for other in per_seed[1:]:
        if other["minutes"] != first["minutes"] or set(other) != set(first):
            raise ValueError("seeds differ in methods or data budgets; aggregate runs of one "
                             "config that differ only in seed")
    out = {"minutes": first["minutes"]}
    for name in first:
        if name == "minutes":
            continue
        if name in REFERENCES:
            out[name] = _aggregate_point([r[name] for r in per_seed])
        else:
            out[name] = [_aggregate_point([r[name][i] for r in per_seed])
                         for i in range(len(first[name]))]
    return out
