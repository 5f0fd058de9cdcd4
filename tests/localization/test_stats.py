"""localization.stats gives the numbers scipy.stats gives (chi-square bit for bit, binomial to 1e-14)."""

import math

import numpy as np
import pytest
from scipy.stats import binom, chi2

from localization.stats import binomial_log_sf, chi2_quantile


@pytest.mark.parametrize("q", [0.5, 0.9, 0.95, 0.99, 0.997, 1 - 1e-6])
def test_chi2_quantiles_equal_scipy_stats(q):
    dof = np.arange(1, 120)
    np.testing.assert_array_equal(chi2_quantile(q, dof), chi2.ppf(q, dof))
    assert chi2_quantile(q, 7) == chi2.ppf(q, 7) and isinstance(chi2_quantile(q, 7), float)
    assert chi2_quantile(0.95, 2) == pytest.approx(5.991464547, abs=1e-9)  # the textbook table


@pytest.mark.parametrize("p", [1e-6, 1e-3, 0.05, 0.3, 0.9])
def test_binomial_tails_equal_scipy_stats(p):
    for n in range(1, 260, 9):
        for k in range(-2, n + 2):
            want = binom.logsf(k, n, p)
            got = binomial_log_sf(k, n, p)
            if math.isinf(want):
                assert got == want, (k, n, p, got)
            else:
                assert got == pytest.approx(want, rel=1e-14, abs=1e-300), (k, n, p, got, want)
    assert binomial_log_sf(0, 1, 0.25) == pytest.approx(math.log(0.25))  # P(X > 0) of one draw
