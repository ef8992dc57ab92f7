"""The profile's [prior] table, --prior-relative's floor and --prior FILE."""
import json

import pytest

from identify import load_profile
from identify.errors import ProfileError
from identify.model.prior import KIN_FLOOR, prior_from_file, relative_prior, with_prior
from identify.model.profile import parse_profile

BASE = """
name = "two"
states = { q = "rad/s", theta = "rad" }
inputs = { de = "rad" }
outputs = ["q", "theta"]
[free]
M_q = -1.0
M_theta = 0.0
M_de = 2.0
[fixed]
theta_q = 1.0
"""


def test_prior_table_both_forms_and_round_trip():
    p = parse_profile(BASE + "[prior]\nM_q = 0.2\nM_de = { value = 2.5, std = 0.5 }\n")
    assert p.prior == {"M_q": {"value": -1.0, "std": 0.2}, "M_de": {"value": 2.5, "std": 0.5}}
    again = parse_profile(p.to_toml())
    assert again.prior == p.prior
    # the centre stays where it was when the start values move (an identified model)
    assert p.with_values({"M_q": -3.0}).prior["M_q"]["value"] == -1.0


@pytest.mark.parametrize("table, needle", [("theta_q = 0.1", "not a free parameter"),
                                           ("M_q = 0.0", "must be positive"),
                                           ("M_q = { std = 0.1, mean = 1 }", "expected"),
                                           ("M_q = \"wide\"", "not a finite number")])
def test_prior_table_errors_name_the_entry(table, needle):
    with pytest.raises(ProfileError, match=needle):
        parse_profile(BASE + "[prior]\n" + table + "\n")


def test_relative_prior_floor_for_values_near_zero():
    prior, none = relative_prior(parse_profile(BASE), 20)
    assert prior["M_q"]["std"] == pytest.approx(0.2)
    # M_theta is a priori 0; its kin (equation M, a variable in rad) is M_de = 2.0 (rad input);
    # M_q's variable is rad/s: M_theta has no kin but itself -> no prior, said
    assert none == ["M_theta"]
    s61 = load_profile("s61_hover_4dof")
    prior, _ = relative_prior(s61, 10)
    # X_u and its kin X_u only (u is the only m/s state in X of the 4-DOF model): its own 10 %
    assert prior["X_u"]["std"] == pytest.approx(0.1 * abs(s61.free["X_u"]))
    # L_theta_s is much smaller than its kin L_theta_c (both rad inputs of L): floor applies
    small, big = abs(s61.free["L_theta_s"]), abs(s61.free["L_theta_c"])
    assert prior["L_theta_s"]["std"] == pytest.approx(0.1 * max(small, KIN_FLOOR * big))


def test_prior_from_result_json(tmp_path):
    p = parse_profile(BASE)
    path = tmp_path / "result.json"
    path.write_text(json.dumps({"parameters": {"M_q": {"value": -1.2, "std": 0.1},
                                               "M_de": {"value": 2.1, "std": None}}}))
    prior, missing = prior_from_file(path, p)
    assert prior == {"M_q": {"value": -1.2, "std": 0.1}}
    assert missing == ["M_theta", "M_de"]
    assert with_prior(p, prior).prior["M_q"]["std"] == 0.1
    bad = tmp_path / "x.toml"
    bad.write_text(BASE)
    with pytest.raises(ProfileError, match="no standard errors"):
        prior_from_file(bad, p)
