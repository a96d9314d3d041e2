"""Summary statistics a result table can be trusted with: mean, IQM, bootstrap 95% CI.

The interquartile mean is ``scipy.stats.trim_mean(x, 0.25)`` (the mean of the middle
50%, as in Agarwal et al.'s rliable) and the confidence interval is SciPy's bootstrap
(BCa, 2000 resamples, seeded so a table is reproducible). Both come from SciPy, which
dm_control already depends on, rather than from hand-written resampling code.
"""

from __future__ import annotations

import numpy as np
from scipy import stats


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
