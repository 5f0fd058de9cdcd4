"""The two distribution tails the localizer's tests need, without importing ``scipy.stats``.

``scipy.stats`` costs about 0.4 s of CPU to import (it loads every distribution), more than the
rest of the package's SciPy; every process that localizes -- a study worker, a trainer's env
copy, a test's subprocess -- paid it for two functions (``tests/localization/test_stats.py``
compares them with ``scipy.stats``):

- :func:`chi2_quantile`: ``chi2.ppf(q, dof) = 2 * gammaincinv(dof / 2, q)``, the formula
  ``scipy.stats`` evaluates: the same numbers bit for bit;
- :func:`binomial_log_sf`: ``binom.logsf(k, n, p) = log P(X > k) = log I_p(k + 1, n - k)``
  (the regularized incomplete beta function) for ``0 <= k < n``; 0 below, -inf from ``n`` on.
  ``scipy.stats`` evaluates the same function through a private Boost binding; the two agree to
  the last bit or two (relative difference below 1e-14).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import betainc, gammaincinv

__all__ = ["binomial_log_sf", "chi2_quantile"]


def chi2_quantile(q: float, dof: ArrayLike) -> NDArray[np.float64] | float:
    """The ``q`` quantile of the chi-square distribution with ``dof`` degrees of freedom.

    ``dof`` may be an array (one quantile each); a scalar ``dof`` gives a float.
    """
    out = 2.0 * gammaincinv(np.asarray(dof, dtype=np.float64) / 2.0, q)
    return float(out) if np.ndim(out) == 0 else out


def binomial_log_sf(k: int, n: int, p: float) -> float:
    """``log P(X > k)`` for ``X ~ Binomial(n, p)``, natural log (``-inf`` when it is 0)."""
    if k < 0:
        return 0.0
    if k >= n:
        return -math.inf
    tail = float(betainc(k + 1, n - k, p))
    return math.log(tail) if tail > 0.0 else -math.inf
