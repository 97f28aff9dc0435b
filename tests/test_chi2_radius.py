"""The gate radii are chi-square quantiles computed without importing scipy.stats (its import
cost ~1.4 s of CPU at every start-up): the same floats as scipy.stats.chi2."""

import numpy as np
from scipy.stats import chi2

from conftest import imported_in_fresh_process

from pfscope.trackers.phd.filter import gate_threshold
from pfscope.trackers.phd.gating import tail_radius2


def test_gate_radii_equal_scipy_stats_chi2():
    for dof in (1, 2, 3, 4, 6):
        for q in np.concatenate([np.linspace(0.01, 0.99, 37), [0.995, 0.999, 0.9999]]):
            assert gate_threshold(float(q), dof) == float(chi2.ppf(q, dof)), (q, dof)
        for tail in (1e-12, 1e-8, 1e-5, 1e-3, 0.01, 0.1, 0.5):
            assert tail_radius2(tail, dof) == float(chi2.isf(tail, dof)), (tail, dof)


def test_radii_do_not_import_scipy_stats():
    code = ("from pfscope.trackers.phd.filter import gate_threshold; "
            "from pfscope.trackers.phd.gating import tail_radius2; "
            "gate_threshold(0.99, 4); tail_radius2(1e-6, 4)")
    assert not imported_in_fresh_process(code, "scipy.stats")
