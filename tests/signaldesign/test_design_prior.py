"""signaldesign with the prior's information: the design maximises what the flight adds to it."""
from dataclasses import replace

import numpy as np
import pytest

from identify import LinearModel, load_profile
from identify.errors import DesignError
from signaldesign.design import SequenceDesign
from signaldesign.quadform import Objective

KW = dict(duration=2.4, record=8.0, grid=0.4, min_pulse=0.4, criterion="nominal")  # 6 steps: exhaustive


@pytest.fixture(scope="module")
def s61():
    prof = load_profile("s61_hover_4dof")
    return prof


def test_prior_criterion_is_log_det_of_prior_plus_flight_information(s61):
    prior = {n: {"value": v, "std": 0.2 * abs(v) + 1e-3} for n, v in s61.free.items()}
    d = SequenceDesign(prior=True, **KW).fit(LinearModel(replace(s61, prior=prior)))
    assert d.result_.method == "exhaustive" and d.bound_ is None
    assert "the prior's information plus the flight's" in d.summary()
    plain = Objective(d.basis_, "nominal")
    P = np.diag([1 / prior[n]["std"] ** 2 for n in d.evaluator_.names])
    with_prior = Objective(d.basis_, "nominal", prior_information=P)
    levels = d.levels_
    r = float(plain.feasible_amplitude(levels)[1])
    M = d.basis_.information(levels)
    expected = np.linalg.slogdet(M / r ** 2 + P)[1]
    assert with_prior(levels) == pytest.approx(expected, rel=1e-9)
    # a negligible prior leaves the design as it was without one
    weak = {n: {"value": v, "std": 1e6 * (abs(v) + 1)} for n, v in s61.free.items()}
    a = SequenceDesign(prior=True, **KW).fit(LinearModel(replace(s61, prior=weak)))
    b = SequenceDesign(**KW).fit(LinearModel(s61))
    np.testing.assert_array_equal(a.levels_, b.levels_)


def test_prior_design_needs_a_prior_and_a_criterion_without_yardsticks(s61):
    with pytest.raises(DesignError, match="no \\[prior\\]"):
        SequenceDesign(prior=True, **KW).fit(LinearModel(s61))
    with pytest.raises(DesignError, match="nominal or mean"):
        SequenceDesign(prior=True, **{**KW, "criterion": "robust"}).fit(
            LinearModel(replace(s61, prior={"M_q": {"value": -0.5, "std": 0.1}})))
