import numpy as np
import pytest

from identify import LinearModel, ProfileError, load_profile, parse_profile, residualize
from identify.model.profile import bundled_profiles_dir

from tests.helpers import one_error_line, run_cli

GOOD = """
name = "test"
states = { u = "m/s", q = "rad/s", theta = "rad" }
inputs = { theta_s = "rad" }
outputs = ["u", "q", "theta", "q_dot", "a_x"]
[output_defs]
a_x = { u_dot = 1.0, theta = 9.81 }
[free]
X_u = -0.02
M_q = -0.6
M_u = 0.01
M_theta_s = 3.1
[fixed]
X_theta = -9.81
theta_q = 1.0
"""


def test_good_profile_builds_matrices():
    p = parse_profile(GOOD)
    m = LinearModel(p)
    assert p.free_names == ["X_u", "M_q", "M_u", "M_theta_s"]
    np.testing.assert_array_equal(m.A, [[-0.02, 0, -9.81], [0.01, -0.6, 0], [0, 1, 0]])
    np.testing.assert_array_equal(m.B, [[0], [3.1], [0]])
    # q_dot is the M equation, a_x = u_dot + g theta = X_u u (the gravity term cancels)
    np.testing.assert_allclose(m.C[3], [0.01, -0.6, 0])
    np.testing.assert_allclose(m.D[3], [3.1])
    np.testing.assert_allclose(m.C[4], [-0.02, 0, 0], atol=1e-15)
    # derivative tensors are exact: A is linear in theta
    theta = np.array([1.0, 2.0, 3.0, 4.0])
    m2 = m.with_theta(theta)
    np.testing.assert_allclose(m2.A - m.A, np.tensordot(theta - m.theta, m.dA, axes=1))
    np.testing.assert_allclose(m2.C - m.C, np.tensordot(theta - m.theta, m.dC, axes=1))


def test_to_toml_round_trip():
    p = parse_profile(GOOD)
    q = parse_profile(p.to_toml())
    assert (q.states, q.inputs, q.outputs, q.free, q.fixed, q.output_defs) == \
        (p.states, p.inputs, p.outputs, p.free, p.fixed, p.output_defs)


def test_ties_act_on_several_entries():
    text = GOOD.replace("[fixed]", "k_lag = 8.0\n[ties]\nk_lag = { M_u = 0.5, X_u = -1.0 }\n[fixed]")
    text = text.replace("X_u = -0.02\n", "").replace("M_u = 0.01\n", "")
    m = LinearModel(parse_profile(text))
    assert m.A[0, 0] == -8.0 and m.A[1, 0] == 4.0


@pytest.mark.parametrize("edit, needle", [
    (("M_q = -0.6", "M_x = -0.6"), "'M_x' names no derivative"),
    (("M_q = -0.6", "K_q = -0.6"), "'K_q'"),
    (("M_q = -0.6", "M_q = -0.6\nM_q = -0.5"), "not valid TOML"),
    (("theta_q = 1.0", "theta_q = 1.0\nM_q = 1.0"), "both free and fixed"),
    (("M_q = -0.6", "M_q = \"fast\""), "M_q = 'fast' is not a number"),
    (("M_q = -0.6", "M_q = true"), "is not a number"),
    (("M_q = -0.6", "M_q = nan"), "not finite"),
    (('inputs = { theta_s = "rad" }', 'inputs = { theta_s = "rad", q = "rad" }'), "both state and input"),
    (('"q_dot", "a_x"]', '"q_dot", "a_x", "w"]'), "term 'w'"),
    (('"q_dot", "a_x"]', '"q_dot", "a_x", "u"]'), "duplicate output"),
    (("name = \"test\"\n", ""), "missing 'name'"),
    (("M_q = -0.6", "M_q = [1, 2]"), "is not a number"),
])
def test_malformed_profiles_give_one_clear_error(edit, needle):
    with pytest.raises(ProfileError) as err:
        parse_profile(GOOD.replace(*edit), source="bad.toml")
    message = str(err.value)
    assert "\n" not in message and message.startswith("bad.toml")
    assert needle in message, message


def test_unknown_top_level_key():
    with pytest.raises(ProfileError, match="unknown key"):
        parse_profile("states2 = 1\n" + GOOD)


def test_bad_profile_on_command_line(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(GOOD.replace("M_q = -0.6", "M_zz = -0.6"))
    one_error_line(run_cli("identify", "model", bad), "bad.toml", "M_zz")
    one_error_line(run_cli("identify", "model", tmp_path / "none.toml"), "none.toml")
    binary = tmp_path / "binary.toml"
    binary.write_bytes(b"\x00\xff\xfe\x81 not text")
    one_error_line(run_cli("identify", "model", binary), "binary.toml", "not a profile")
    bom = tmp_path / "bom.toml"
    bom.write_text("\ufeff" + GOOD, encoding="utf-8")
    assert load_profile(bom).free == parse_profile(GOOD).free


@pytest.mark.parametrize("path", sorted(bundled_profiles_dir().glob("*.toml")), ids=lambda p: p.stem)
def test_bundled_profiles_parse_and_round_trip(path):
    p = load_profile(path)
    m = LinearModel(p)
    assert np.all(np.isfinite(m.A)) and m.A.shape == (len(p.states),) * 2
    q = parse_profile(p.to_toml())
    assert q.free == p.free and q.fixed == p.fixed


def _pairs(model):
    return [m for m in model.modes() if m.oscillatory and not m.stable]


def test_s61_has_the_papers_two_unstable_pairs(s61):
    pairs = _pairs(s61)
    assert len(pairs) == 2
    np.testing.assert_allclose(sorted(m.frequency for m in pairs), [0.36, 0.50], atol=0.01)


def test_s61_4dof_profile_is_the_residualised_8_state_model(s61):
    shipped = load_profile("s61_hover_4dof")
    reduced = residualize(s61, ["theta_R", "phi_R"])
    assert shipped.states == reduced.states and set(shipped.fixed) == set(reduced.fixed)
    assert set(shipped.free) == set(reduced.free)
    a, b = LinearModel(shipped), LinearModel(reduced)
    np.testing.assert_allclose(a.A, b.A, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(a.B, b.B, rtol=1e-10, atol=1e-14)
    # residualisation keeps the slow modes: the two unstable pairs stay near 0.36 and 0.5 rad/s
    np.testing.assert_allclose(sorted(m.frequency for m in _pairs(a)), [0.36, 0.50], atol=0.01)


def test_residualisation_matches_the_fast_limit():
    """Shrinking the rotor time constant makes the full model approach its reduction."""
    text = """
name = "lag"
states = { x = "-", f = "-" }
inputs = { d = "-" }
outputs = ["x"]
[fixed]
x_x = -1.0
x_f = 2.0
f_f = -50.0
f_x = 25.0
f_d = 50.0
"""
    r = LinearModel(residualize(LinearModel(parse_profile(text)), ["f"]))
    np.testing.assert_allclose(r.A, [[-1.0 + 2.0 * 25 / 50]])
    np.testing.assert_allclose(r.B, [[2.0]])


def test_model_command_prints_modes():
    proc = run_cli("identify", "model", "profiles/s61_hover_8state.toml", "--reduce", "theta_R,phi_R")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.count("UNSTABLE") == 4  # two pairs, in the full and in the reduced model
    assert "0.3602" in proc.stdout and "0.4997" in proc.stdout


def test_output_equation_parameters_scale_and_offset():
    """Ties may act on C and D: a scale factor on an output, a term from an input channel."""
    text = GOOD.replace("[fixed]", 'k_q = 0.1\nd_u = 0.5\n[ties]\nk_q = { "q:q" = 1.0 }\nd_u = { "u:theta_s" = 1.0 }\n[fixed]')
    m = LinearModel(parse_profile(text))
    assert m.C[1, 1] == pytest.approx(1.1) and m.D[0, 0] == pytest.approx(0.5)
    i = m.names.index("k_q")
    np.testing.assert_allclose(m.with_theta(m.theta + np.eye(len(m.theta))[i]).C - m.C, m.dC[i])
    with pytest.raises(ProfileError, match="'zz' is not an output"):
        parse_profile(text.replace('"q:q"', '"zz:q"'))
    with pytest.raises(ProfileError, match="'w' is not a state or input"):
        parse_profile(text.replace('"q:q"', '"q:w"'))


def test_one_unit_rule_for_outputs():
    """Plots and the assumed noise levels read output units from one rule: derivatives in
    <unit>/s (rad/s/s as rad/s^2), defined outputs from their derivative term, inputs their own."""
    from identify import output_units
    p = load_profile("bo105_70kt")
    units = output_units(p)
    assert units["q"] == "rad/s" and units["theta"] == "rad" and units["u"] == "m/s"
    assert units["a_x"] == "m/s^2" and units["a_z"] == "m/s^2"
    p2 = parse_profile("""
name = "t"
states = { q = "rad/s", theta = "rad" }
inputs = { eta = "rad" }
outputs = ["q_dot", "theta", "eta", "mix"]
[output_defs]
mix = { eta = 2.0 }
[free]
M_q = -1.0
M_eta = 1.0
[fixed]
theta_q = 1.0
""")
    assert output_units(p2) == {"q_dot": "rad/s^2", "theta": "rad", "eta": "rad", "mix": ""}


def test_limits_are_read_validated_and_written_back():
    base = 'name = "x"\nstates = { q = "rad/s", theta = "rad" }\ninputs = { e = "rad" }\noutputs = ["q", "theta"]\n' \
           '[free]\nM_q = -1.0\nM_e = 2.0\n[fixed]\ntheta_q = 1.0\n'
    p = parse_profile(base + "[limits]\ntheta = 0.17\n")
    assert p.limits == {"theta": 0.17}
    assert parse_profile(p.to_toml()).limits == {"theta": 0.17}
    with pytest.raises(ProfileError, match=r"\[limits\] zz: not an output"):
        parse_profile(base + "[limits]\nzz = 1.0\n")
    with pytest.raises(ProfileError, match=r"\[limits\] q = 0 must be positive"):
        parse_profile(base + "[limits]\nq = 0\n")


def test_every_bundled_profile_limits_every_output():
    for name in ("s61_hover_8state", "s61_hover_4dof", "bo105_70kt", "navion_cruise_long", "hover_4input"):
        p = load_profile(name)
        assert set(p.limits) == set(p.outputs), name


def test_modes_table_is_honest_about_real_and_zero_eigenvalues():
    from identify.model.linear import format_modes, modes_of
    table = format_modes(modes_of(np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 2.0], [0.0, -2.0, -1.0]])))
    zero, pair = table.splitlines()[1:]
    assert "nan" not in table and "inf" not in table
    assert zero.split()[-1] == "neutral" and zero.split()[2:5] == ["-", "-", "-"]
    assert pair.split()[-1] == "stable" and "3.14" in pair
    unstable = format_modes(modes_of(np.array([[0.5]])))
    assert unstable.splitlines()[1].split()[-1] == "UNSTABLE" and " - " in unstable
