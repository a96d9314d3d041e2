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
