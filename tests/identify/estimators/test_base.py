"""The estimators' common contract (scikit-learn style) and the method registry."""
import math

import numpy as np
import pytest

from identify import IV, LS, ML, EstimationError, ProfileError, simulate_run
from identify.estimators.frequency.equation_error import FDEE
from identify.estimators.frequency.response_fit import FR
from identify.estimators.registry import METHODS, estimator_class


@pytest.fixture(scope="module")
def run(s61):
    t = np.arange(1001) * 0.01
    u = np.column_stack([0.02 * ((t > 1) & (t < 2)) - 0.02 * ((t > 2) & (t < 3)),
                         0.02 * ((t > 5) & (t < 6)) - 0.02 * ((t > 6) & (t < 7))])
    return simulate_run(s61, t, u, seed=0)


def test_estimators_store_in_init_and_validate_in_fit(s61, run):
    """__init__ keeps the arguments as given (no file read, no conversion); fit loads the profile
    (profile_) and raises the one-line error on a bad one or a bad option."""
    for cls in (ML, LS, IV, FDEE):
        est = cls("no_such_profile")
        assert est.profile == "no_such_profile"
        with pytest.raises(ProfileError, match="no_such_profile"):
            est.fit(run)
    est = ML(s61.profile, segment="plain", max_iter=3)
    assert est.segment == "plain" and not hasattr(est, "segment_")
    assert est.fit(run) is est
    assert est.segment_ == math.inf and est.profile_ is s61.profile
    with pytest.raises(EstimationError, match="max_iter"):
        IV(s61.profile, max_iter=0).fit(run)
    with pytest.raises(EstimationError, match="band"):
        FDEE(s61.profile, band=(2.0, 1.0)).fit(run)


def test_one_registry_names_the_methods():
    assert METHODS == {"ml": ML, "ls": LS, "iv": IV, "fdee": FDEE, "fr": FR}
    assert estimator_class("iv") is IV
    with pytest.raises(EstimationError, match="unknown method 'ekf'.*ml, ls, iv"):
        estimator_class("ekf")
