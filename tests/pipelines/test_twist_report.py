"""The TWIST table's statistics come from SciPy (IQM, bootstrap CI stratified by seed)."""

import numpy as np
import pytest
from scipy import stats

from simdist.pipelines.twist_report import ORACLE, format_table, summarise


def test_twist_summary_matches_scipy_and_stratifies_by_seed():
    rng = np.random.default_rng(0)
    seeds = [list(rng.normal(300 + 100 * s, 30, 10)) for s in range(3)]
    oracle = [600.0, 700.0, 800.0]
    results = {"task": {ORACLE: {"returns": oracle},
                        "TWIST": {"returns": sum(seeds, []), "seed_returns": seeds}}}
    s = summarise(results)["task"]["TWIST"]
    pooled = np.concatenate(seeds)
    assert s["mean"] == pytest.approx(pooled.mean())
    assert s["normalised"] == pytest.approx(pooled.mean() / 700.0)
    assert s["normalised_iqm"] == pytest.approx(stats.trim_mean(pooled / 700.0, 0.25))
    assert s["seeds"] == 3 and s["episodes"] == 30
    assert s["std_over_seeds"] == pytest.approx(np.std([np.mean(g) for g in seeds]))
    assert s["normalised_ci_low"] < s["normalised"] < s["normalised_ci_high"]
    # the interval resamples within seeds: it is narrower than one that ignores them
    unstratified = summarise({"task": {ORACLE: {"returns": oracle},
                                       "TWIST": {"returns": list(pooled)}}})["task"]["TWIST"]
    assert (s["normalised_ci_high"] - s["normalised_ci_low"]) < \
        (unstratified["normalised_ci_high"] - unstratified["normalised_ci_low"])
    assert "IQM" in format_table(results) and "[" in format_table(results)
    # and the interval over seeds (seeds resampled) spans the seeds' gap the other omits
    low, high = s["normalised_ci_seeds"]
    assert low < s["normalised_ci_low"] and s["normalised_ci_high"] < high
    assert "normalised_ci_seeds" not in unstratified  # one seed: nothing to resample


def test_twist_summary_needs_the_oracle():
    with pytest.raises(KeyError, match="Oracle"):
        summarise({"task": {"TWIST": {"returns": [1.0, 2.0]}}})
