"""refine's report: a parameter whose standard error is not determined (NaN, None in refine.json:
the final fit did not converge) is said so in report.md; it crashed the report
(benchmarks/refine_blind.py null_s61 seed 10: the declared S 61 fit stopped at 100 iterations)."""
from identify.refine.report import _value_std


def test_an_undetermined_standard_error_is_said_not_a_crash():
    assert _value_std({"name": "X_u", "value": -0.078, "std": None}) == \
        "`X_u` = -0.078 ± (standard error not determined)"
    assert _value_std({"name": "X_u", "value": -0.078, "std": float("nan")}).endswith("not determined)")
    assert _value_std({"name": "M_q", "value": -0.15, "std": 0.0123}) == "`M_q` = -0.15 ± 0.012"
