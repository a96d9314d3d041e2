"""Two finished SimDist recipe runs compared episode by episode on the same worlds.

The recipe pairs its own methods by episode; this pairs one method across two runs, e.g.
two settings of a flag trained on the same expert, dataset and evaluation worlds (a
seed's worlds depend only on the seed and target). Each run is a recipe output folder:
one seed's, or a multi-seed folder after ``--seeds`` (the pairing is then stratified by
seed). It prints both runs' rows of the method, the first run minus the second at every
budget (mean [bootstrap 95% CI of the per-episode differences]) and the first run's own
gain over its zero-shot point; it refuses runs whose episodes are not the same worlds
(other seeds or targets, different episode counts or commanded speeds).

With several seeds it also prints each seed's difference and the interval over seeds
(the seeds resampled, their episodes travelling with them). Two runs that each pretrained
anew differ by more than their episodes: a pretraining's small numerical differences alone
move one seed's figure by ten points or more (the default's seed 0 at 8 minutes: 53% with
one torch thread, 66% with two and the faster SimNorm kernel; README, Recipe section and
Results), and the per-episode interval keeps the seeds fixed, so it cannot see that. Read
a claim about a flag from the seed-level line; three seeds allow only ten seed multisets,
so that interval is coarse: state the seed count beside it.

    python experiments/compare_runs.py --run results/simdist_residual_logit_3seeds_2026-12-03 \\
        --against results/simdist_residual_additive_3seeds_2026-12-03 --names logit additive
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from simdist.pipelines.report import REFERENCES, format_paired_differences, format_table
from simdist.pipelines.statistics import summarise_groups
from simdist.pipelines.simdist import SIMDIST


def paired_curves(first: dict, second: dict, method: str, names: tuple[str, str]) -> dict:
    """A results dict holding ``method``'s points of two runs under ``names``.

    Examples:
        >>> p = lambda f: {"fraction": f, "progress_m": f, "mean_m": 0.0, "std_m": 0.0,
        ...                "mean_fraction": sum(f) / len(f), "std_fraction": 0.0}
        >>> a = {"minutes": [0.0, 8.0], "m": [p([0.1, 0.3]), p([0.5, 0.7])]}
        >>> b = {"minutes": [0.0, 8.0], "m": [p([0.1, 0.1]), p([0.2, 0.4])]}
        >>> sorted(paired_curves(a, b, "m", ("A", "B")))
        ['A', 'B', 'minutes']
    """
    for curves in (first, second):
        if method not in curves:
            raise SystemExit(f"no method {method!r} in a run; it has "
                             f"{[k for k in curves if k != 'minutes' and k not in REFERENCES]}")
    if first["minutes"] != second["minutes"]:
        raise SystemExit(f"the runs' budgets differ: {first['minutes']} vs {second['minutes']}")
    return {"minutes": first["minutes"], names[0]: first[method], names[1]: second[method]}


def seed_differences(curves: dict, names: tuple[str, str]) -> list[dict] | None:
    """Per budget: each seed's mean difference (first minus second, points of the commanded
    distance) and the cluster-bootstrap interval over seeds; ``None`` for a single seed
    or points without per-seed episode counts.

    Examples:
        >>> p = lambda f: {"fraction": f, "seed_episodes": [2, 2, 2]}
        >>> c = {"minutes": [8.0], "A": [p([.5, .7, .4, .4, .9, .7])],
        ...      "B": [p([.4, .6, .4, .4, .6, .6])]}
        >>> row = seed_differences(c, ("A", "B"))[0]
        >>> [round(d) for d in row["seeds"]], row["low"] <= row["mean"] <= row["high"]
        ([10, 0, 20], True)
    """
    rows = []
    for first, second in zip(curves[names[0]], curves[names[1]]):
        sizes = first.get("seed_episodes")
        if (not sizes or len(sizes) < 2 or sizes != second.get("seed_episodes")
                or sum(sizes) != len(first["fraction"])):
            return None
        diff = 100 * (np.asarray(first["fraction"]) - np.asarray(second["fraction"]))
        s = summarise_groups(np.split(diff, np.cumsum(sizes)[:-1]))
        rows.append({"seeds": s["group_means"], "mean": s["mean"],
                     "low": s["ci_seeds_low"], "high": s["ci_seeds_high"]})
    return rows


def format_seed_differences(rows: list[dict], minutes: list[float], names) -> str:
    """The lines :func:`main` prints for :func:`seed_differences`."""
    lines = [f"{names[0]} minus {names[1]} by seed (points; mean [95% interval over seeds, "
             f"{len(rows[0]['seeds'])} seeds])"]
    for m, row in zip(minutes, rows):
        per_seed = " / ".join(f"{d:+.0f}" for d in row["seeds"])
        lines.append(f"  {m:5.2f} min: {per_seed}; {row['mean']:+.0f} "
                     f"[{row['low']:+.0f}, {row['high']:+.0f}]")
    return "\n".join(lines)


def read_run(run: Path) -> dict:
    path = run / "results.json"
    if not path.exists():
        raise SystemExit(f"no results.json in {run}: is the run finished?")
    return json.loads(path.read_text())


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", required=True, type=Path, help="the first run's folder")
    parser.add_argument("--against", required=True, type=Path, help="the second run's folder")
    parser.add_argument("--method", default=SIMDIST, help="the method to pair (a row name)")
    parser.add_argument("--names", nargs=2, default=("first", "second"),
                        help="labels of the two runs in the tables")
    args = parser.parse_args(argv)
    first, second = read_run(args.run), read_run(args.against)
    seeds = [run["config"].get("seeds") or [run["config"]["seed"]] for run in (first, second)]
    if seeds[0] != seeds[1]:
        raise SystemExit(f"the runs hold other seeds ({seeds[0]} vs {seeds[1]}): their "
                         "episodes are not the same worlds")
    targets = {first["config"]["target"], second["config"]["target"]}
    if len(targets) != 1:
        raise SystemExit(f"the runs deployed in different targets: {sorted(targets)}")
    target = targets.pop()
    curves = paired_curves(first["curves"], second["curves"], args.method, tuple(args.names))
    print(format_table(curves, target))
    paired = format_paired_differences(curves, target, args.names[0])
    if paired is None:
        raise SystemExit("the runs' episodes are not the same worlds (episode counts or "
                         "commanded speeds differ): they cannot be paired")
    print("\n" + paired)
    by_seed = seed_differences(curves, tuple(args.names))
    if by_seed is not None:
        print("\n" + format_seed_differences(by_seed, curves["minutes"], args.names))


if __name__ == "__main__":
    main()
