import numpy as np
import pytest
from scipy import stats

from simdist.pipelines.statistics import summarise, summarise_groups


def test_grouped_summary_pools_values_and_stratifies_the_bootstrap():
    rng = np.random.default_rng(0)
    groups = [rng.normal(m, 0.2, 32) for m in (0.2, 0.5, 0.8)]
    s = summarise_groups(groups)
    pooled = np.concatenate(groups)
    assert s["mean"] == pytest.approx(pooled.mean())
    assert s["iqm"] == pytest.approx(stats.trim_mean(pooled, 0.25))
    assert s["group_means"] == pytest.approx([g.mean() for g in groups])
    assert s["std_over_seeds"] == pytest.approx(np.std([g.mean() for g in groups]))
    # Resampling within seeds removes the between-seed component an i.i.d. bootstrap of the
    # pooled values would include: the stratified interval is narrower.
    iid = summarise(pooled)
    assert s["ci_low"] < s["mean"] < s["ci_high"]
    assert s["ci_high"] - s["ci_low"] < iid["ci_high"] - iid["ci_low"]
    # Within-seed standard error of the pooled mean: sqrt(sum var_g / n_g) / k.
    se = np.sqrt(sum(g.var(ddof=1) / g.size for g in groups)) / len(groups)
    assert s["ci_high"] - s["ci_low"] == pytest.approx(2 * 1.96 * se, rel=0.15)


def test_grouped_summary_rejects_empty_groups_and_non_finite_values():
    with pytest.raises(ValueError, match="non-empty"):
        summarise_groups([[0.1], []])
    with pytest.raises(ValueError, match="finite"):
        summarise_groups([[0.1, float("nan")]])


def test_the_interval_over_seeds_counts_the_spread_between_seeds():
    from simdist.pipelines.statistics import interval_over_seeds
    rng = np.random.default_rng(1)
    # Three seeds whose means differ far more than their episodes' noise can explain: the
    # stratified interval only measures the episodes, the one over seeds includes the gap.
    groups = [rng.normal(m, 0.05, 32) for m in (-0.1, 0.1, 0.4)]
    s = summarise_groups(groups)
    assert s["ci_seeds_low"] < s["ci_low"] and s["ci_high"] < s["ci_seeds_high"]
    assert s["ci_seeds_low"] <= s["mean"] <= s["ci_seeds_high"]
    assert interval_over_seeds(groups) == (s["ci_seeds_low"], s["ci_seeds_high"])  # seeded

    # Many seeds of equal size: a bootstrap of the seed means, whose standard error is the
    # seeds' population std / sqrt(k) (constant episodes: nothing else varies).
    means = rng.normal(0.3, 0.2, 200)
    low, high = interval_over_seeds([np.full(8, m) for m in means], resamples=4000)
    assert high - low == pytest.approx(2 * 1.96 * means.std() / np.sqrt(means.size), rel=0.1)

    # Seeds that are draws of one distribution: the episodes' noise counted once, so close
    # to the i.i.d. interval of the pool (a two-level resampling would be ~sqrt(2) wider).
    same = [rng.normal(0.0, 1.0, 64) for _ in range(20)]
    low, high = interval_over_seeds(same, resamples=4000)
    iid = summarise(np.concatenate(same))
    assert high - low == pytest.approx(iid["ci_high"] - iid["ci_low"], rel=0.2)


def test_the_interval_over_seeds_refuses_what_it_cannot_resample():
    from simdist.pipelines.statistics import interval_over_seeds
    with pytest.raises(ValueError, match="two non-empty"):
        interval_over_seeds([[0.1, 0.2]])
    with pytest.raises(ValueError, match="finite"):
        interval_over_seeds([[0.1, 0.2], [float("inf"), 0.3]])
    assert "ci_seeds_low" not in summarise_groups([[0.1, 0.2, 0.3]])  # one seed: none


def test_the_results_table_shows_the_interval_over_seeds_when_seeds_were_pooled():
    from simdist.pipelines.report import aggregate_seeds, format_table
    point = lambda f: {"fraction": f, "progress_m": f, "return": 1.0}
    runs = [{"minutes": [0.0], "m": [point([0.1, 0.2, 0.3])]},
            {"minutes": [0.0], "m": [point([0.6, 0.7, 0.8])]}]
    merged = aggregate_seeds(runs)
    low, high = merged["m"][0]["ci_fraction_seeds"]
    table = format_table(merged, "ice")
    assert "CI over seeds" in table and f"[{100 * low:4.0f}, {100 * high:4.0f}]%" in table
    one_seed = aggregate_seeds(runs[:1])
    assert "CI over seeds" not in format_table(one_seed, "ice")  # one seed: no such column


def test_the_table_by_commanded_speed_splits_each_point_by_its_episodes_speeds():
    from simdist.pipelines.report import aggregate_seeds, format_by_command
    point = lambda f, c: {"fraction": f, "progress_m": f, "command_mps": c, "return": 1.0}
    runs = [{"minutes": [0.0], "m": [point([-1.0, 0.6, 0.8], [0.25, 0.75, 0.75])]},
            {"minutes": [0.0], "m": [point([-0.5, 0.7, 0.9], [0.25, 0.25, 0.75])]}]
    merged = aggregate_seeds(runs)
    assert merged["m"][0]["command_mps"] == [0.25, 0.75, 0.75, 0.25, 0.25, 0.75]
    table = format_by_command(merged, "ice").splitlines()
    assert "0.25 m/s" in table[1] and "0.75 m/s" in table[1]
    # 0.25 m/s: (-1.0 - 0.5 + 0.7) / 3 = -27%; 0.75 m/s: (0.6 + 0.8 + 0.9) / 3 = 77%
    assert "-27% [" in table[2] and "] (3)" in table[2] and "77% [" in table[2]
    # records written before the speeds were kept: no table rather than a wrong one
    old = {"minutes": [0.0], "m": [{"fraction": [0.1], "progress_m": [0.1], "return": 1.0}]}
    assert format_by_command(old, "ice") is None
    assert "command_mps" not in aggregate_seeds([runs[0], old])["m"][0]


def test_the_roll_table_marks_points_recorded_before_rolls_were_kept():
    from simdist.pipelines.report import format_upside_down
    new = {"fraction": [0.1, -0.3], "command_mps": [0.25, 0.5], "upside_down": [False, True]}
    old = {"fraction": [0.2, 0.4], "command_mps": [0.25, 0.5]}  # a reused older record
    lines = format_upside_down({"minutes": [0.0, 8.0], "m": [old, new]}, "ice").splitlines()
    assert lines[2].split()[-2:] == ["n/a", "n/a"]
    assert lines[3].split()[-2:] == ["0/1", "1/1"]
    # no point recorded rolls: no table at all
    assert format_upside_down({"minutes": [0.0], "m": [old]}, "ice") is None


def test_the_tracking_table_counts_overshooting_as_error_not_as_progress():
    from simdist.pipelines.report import format_table, format_tracking_error
    point = lambda f: {"fraction": f, "progress_m": f, "mean_m": 1.0, "std_m": 0.0,
                       "mean_fraction": sum(f) / len(f), "return": 1.0}
    # "fast" walks 150% of every command: a higher mean fraction, a worse tracking
    results = {"minutes": [8.0], "exact": [point([1.0, 0.96, 1.04, 1.0])],
               "fast": [point([1.5, 1.5, 1.5, 1.5])]}
    assert "150%" in format_table(results, "ice")
    exact, fast = format_tracking_error(results, "ice").splitlines()[2:]
    assert exact.startswith("exact") and "  2% [" in exact and exact.endswith(" 0%")
    assert fast.startswith("fast") and " 50% [  50,   50]" in fast and fast.endswith(" 100%")


def test_paired_differences_are_per_episode_stratified_by_seed_and_refuse_other_worlds():
    from simdist.pipelines.report import aggregate_seeds, format_paired_differences
    from simdist.pipelines.statistics import summarise_groups
    point = lambda f, c: {"fraction": f, "progress_m": f, "command_mps": c, "return": 1.0}
    speeds = [0.25, 0.5, 0.75, 0.25]
    # the worlds vary a lot (-0.5 .. 0.9) and "mine" is 0.1 above "other" on each of them
    worlds = [[-0.5, 0.1, 0.9, 0.3], [0.2, -0.4, 0.6, 0.0]]
    better = lambda w: [x + 0.1 + 0.01 * i for i, x in enumerate(w)]  # noqa: E731
    runs = [{"minutes": [0.0, 8.0], "mine": [point(w, speeds), point(better(w), speeds)],
             "other": [point(w, speeds), point(w, speeds)]} for w in worlds]
    merged = aggregate_seeds(runs)
    assert merged["mine"][1]["seed_episodes"] == [4, 4]
    lines = format_paired_differences(merged, "ice", "mine").splitlines()
    assert "stratified by seed" in lines[0]
    own, other = lines[2], lines[3]
    # against its own first point and against "other": +10, +11, +12, +13 points per seed
    expected = summarise_groups([[10.0, 11.0, 12.0, 13.0]] * 2)
    cell = f"{expected['mean']:+4.0f} [{expected['ci_low']:+5.0f}, {expected['ci_high']:+5.0f}]"
    assert own.endswith(cell) and other.endswith(cell) and other.startswith("other")
    # paired, the interval is a few points wide; the methods' own intervals are not
    assert expected["ci_high"] - expected["ci_low"] < 5
    ci = merged["mine"][1]["ci_fraction"]
    assert 100 * (ci[1] - ci[0]) > 20
    # points of different worlds (another speed drawn) cannot be paired: no table
    runs[0]["other"][1] = point(worlds[0], [0.75, 0.5, 0.75, 0.25])
    assert format_paired_differences(aggregate_seeds(runs), "ice", "mine") is None
    assert format_paired_differences(merged, "ice", "absent") is None


def test_paired_differences_pool_points_split_by_seed_differently():
    from simdist.pipelines.report import format_paired_differences
    grouped = {"fraction": [0.5, 0.6, 0.7, 0.8], "seed_episodes": [2, 2]}
    single = {"fraction": [0.1, 0.2, 0.3, 0.4]}  # a record written without episode counts
    table = format_paired_differences({"minutes": [8.0], "mine": [grouped], "old": [single]},
                                      "ice", "mine")
    assert table.splitlines()[3].startswith("old") and "+40 [  +40,   +40]" in table
