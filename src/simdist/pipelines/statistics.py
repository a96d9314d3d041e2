"""Summary statistics a result table can be trusted with: mean, IQM, bootstrap 95% CI.

The interquartile mean is ``scipy.stats.trim_mean(x, 0.25)`` (the mean of the middle
50%, as in Agarwal et al.'s rliable) and the confidence interval is SciPy's bootstrap
(BCa, 2000 resamples, seeded so a table is reproducible). Both come from SciPy, which
dm_control already depends on, rather than from hand-written resampling code.
"""

from __future__ import annotations

import numpy as np

from simdist.utils.lazy import lazy_import

stats = lazy_import("scipy.stats")  # ~1 s to import: loaded when a table is first made


def summarise(values, confidence: float = 0.95, resamples: int = 2000, seed: int = 0) -> dict:
    """``{"mean", "std", "iqm", "ci_low", "ci_high", "n"}`` of the mean of ``values``.

    Args:
        values: one number per episode (or per seed).
        confidence: confidence level of the interval.
        resamples: bootstrap resamples.
        seed: seed of the bootstrap's generator.

    Examples:
        >>> s = summarise([0.1, 0.2, 0.3, 0.4, 10.0])
        >>> round(s["mean"], 2), round(s["iqm"], 2), s["n"]
        (2.2, 0.3, 5)
        >>> s["ci_low"] <= s["mean"] <= s["ci_high"]
        True
    """
    x = np.asarray(values, dtype=np.float64).ravel()
    if x.size == 0 or not np.isfinite(x).all():
        raise ValueError(f"summarise needs finite values, got {x.tolist()}")
    out = {"mean": float(x.mean()), "std": float(x.std()), "iqm": float(stats.trim_mean(x, 0.25)),
           "n": int(x.size)}
    if x.size < 2 or np.all(x == x[0]):  # no spread: the interval is the point
        out["ci_low"] = out["ci_high"] = out["mean"]
        return out
    ci = stats.bootstrap((x,), np.mean, confidence_level=confidence, n_resamples=resamples,
                         method="BCa", random_state=np.random.default_rng(seed)).confidence_interval
    low, high = float(ci.low), float(ci.high)
    if not (np.isfinite(low) and np.isfinite(high)):  # BCa degenerates on tiny samples
        ci = stats.bootstrap((x,), np.mean, confidence_level=confidence, n_resamples=resamples,
                             method="percentile",
                             random_state=np.random.default_rng(seed)).confidence_interval
        low, high = float(ci.low), float(ci.high)
    out["ci_low"], out["ci_high"] = low, high
    return out


def summarise_groups(groups, confidence: float = 0.95, resamples: int = 2000,
                     seed: int = 0) -> dict:
    """Like :func:`summarise` over all values of ``groups`` (one list per seed), with the
    bootstrap stratified by group and each group's own mean.

    The interval resamples episodes within each seed (SciPy's multi-sample bootstrap, the
    stratified bootstrap rliable uses across tasks), so it measures episode-to-episode
    variation of these seeds; ``std_over_seeds`` is the spread between seeds, reported
    beside it rather than folded in. ``ci_seeds_low``/``ci_seeds_high`` (two or more
    groups) is :func:`interval_over_seeds`: the interval that does fold it in.

    Examples:
        >>> s = summarise_groups([[0.1, 0.2, 0.3], [0.5, 0.6, 0.7]])
        >>> round(s["mean"], 2), [round(m, 2) for m in s["group_means"]], s["n"]
        (0.4, [0.2, 0.6], 6)
        >>> s["ci_low"] < 0.4 < s["ci_high"]
        True
    """
    groups = [np.asarray(g, dtype=np.float64).ravel() for g in groups]
    if not groups or any(g.size == 0 for g in groups):
        raise ValueError("summarise_groups needs at least one non-empty group per seed")
    pooled = np.concatenate(groups)
    out = summarise(pooled, confidence, resamples, seed)
    means = [float(g.mean()) for g in groups]
    out["group_means"], out["std_over_seeds"] = means, float(np.std(means))
    if len(groups) > 1:
        out["ci_seeds_low"], out["ci_seeds_high"] = interval_over_seeds(
            groups, confidence, resamples, seed)
    if len(groups) == 1 or out["ci_low"] == out["ci_high"] or any(g.size < 2 for g in groups):
        return out

    def pooled_mean(*samples, axis=-1):
        return np.concatenate(samples, axis=axis).mean(axis=axis)

    ci = stats.bootstrap(tuple(groups), pooled_mean, confidence_level=confidence,
                         n_resamples=resamples, method="percentile", vectorized=True,
                         random_state=np.random.default_rng(seed)).confidence_interval
    out["ci_low"], out["ci_high"] = float(ci.low), float(ci.high)
    return out


def interval_over_seeds(groups, confidence: float = 0.95, resamples: int = 2000,
                        seed: int = 0) -> tuple[float, float]:
    """Percentile bootstrap interval of the pooled mean when the seeds are the sample.

    Each resample draws as many seeds as there are, with replacement, and pools their
    episodes as they are (the cluster bootstrap: the seed is the unit of resampling, its
    episodes travel with it, so their noise counts once, through the seed's mean;
    resampling the episodes again inside each seed would count it twice). The stratified
    interval of :func:`summarise_groups` keeps the seeds fixed, so it says how precisely
    *these* seeds were measured; this one also counts how far the figure moves from one
    seed (one pretraining, one teacher) to the next, the interval to read when a claim is
    about the method rather than about these seeds. With few seeds it is coarse (three
    seeds allow only ten seed multisets) and, like any bootstrap of few units, narrower
    than a t-interval would be: state the seed count beside it. SciPy's bootstrap resamples
    values, not groups of values, hence the explicit draw.

    Examples:
        >>> low, high = interval_over_seeds([[0.0, 0.1], [0.5, 0.6], [0.9, 1.0]])
        >>> low < 0.2 and high > 0.8
        True
    """
    groups = [np.asarray(g, dtype=np.float64).ravel() for g in groups]
    if len(groups) < 2 or any(g.size == 0 for g in groups):
        raise ValueError("interval_over_seeds needs at least two non-empty groups")
    if not all(np.isfinite(g).all() for g in groups):
        raise ValueError("interval_over_seeds needs finite values")
    sums = np.array([g.sum() for g in groups])
    sizes = np.array([g.size for g in groups], dtype=np.float64)
    picks = np.random.default_rng(seed).integers(0, len(groups), (resamples, len(groups)))
    means = sums[picks].sum(1) / sizes[picks].sum(1)  # pooled mean of each seed draw
    alpha = (1.0 - confidence) / 2.0
    return float(np.quantile(means, alpha)), float(np.quantile(means, 1.0 - alpha))
