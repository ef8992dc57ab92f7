"""Filter-error method: known process and measurement noise recovered, ML when F = 0, a lateral
model with acceleration outputs, known x0 and an output without zero shift, the command line."""
import json
import math

import numpy as np
import pytest

from identify import ML, LinearModel, load_profile, parse_profile, simulate_run
from identify.errors import EstimationError
from identify.estimators.filter_error import FEM
from identify.estimators.registry import estimator_class
from tests.identify.test_cli import _in_process

DT = 0.02
F_TRUE = {"u": 0.3, "w": 0.6}  # m/s / sqrt(s)
NOISE = {"u": 0.05, "w": 0.05, "q": 0.002, "theta": 0.001}


def _elevator(t):
    u = np.zeros_like(t)
    u[(t > 1) & (t < 2)], u[(t > 2) & (t < 3)], u[(t > 8) & (t < 12)] = 0.02, -0.02, 0.01
    return u


@pytest.fixture(scope="module")
def navion():
    return load_profile("navion_cruise_long")


def _runs(model, F, seeds, duration=30.0):
    """Runs with process noise F (unit white noise; simulate_run's per-sample sigma = F / sqrt(dt))."""
    t = np.arange(0, duration, DT)
    sigma = [F.get(s, 0.0) / math.sqrt(DT) for s in model.profile.state_names]
    return [simulate_run(model, t, _elevator(t), noise=NOISE, process_noise=sigma, seed=s) for s in seeds]


def _off(profile, factor=1.2):
    return profile.with_values({k: v * factor for k, v in profile.free.items()})


def test_recovers_known_process_and_measurement_noise(navion):
    truth = LinearModel(navion)
    fem = FEM(_off(navion)).fit(_runs(truth, F_TRUE, (0, 1)))
    info = fem.result_.info
    assert info["converged"] and fem.result_.method == "fem"
    for s, F in F_TRUE.items():  # the default process noise: the velocity states u, w
        entry = info["process_noise"][s]
        assert abs(entry["F"] - F) < 3 * entry["std"] and entry["std"] < 0.1 * F, (s, entry)
    for y, sd in NOISE.items():
        entry = info["measurement_noise"][y]
        assert abs(entry["variance"] - sd ** 2) < 3 * entry["std"] and entry["std"] < 0.2 * sd ** 2, (y, entry)
    assert np.all(info["diag_CK"] <= 1.0) and "unit white noise" in info["process_noise_convention"]
    z = (fem.theta_ - truth.theta) / fem.std_
    assert np.all(np.abs(z) < 3), dict(zip(truth.names, z.round(2)))


def test_without_process_noise_fem_is_output_error_ml(navion):
    truth = LinearModel(navion)
    runs = _runs(truth, {}, (3,), duration=20.0)
    ml = ML(_off(navion), segment="plain", coloured=False).fit(runs)
    fem = FEM(_off(navion), process_noise={}).fit(runs)
    assert fem.result_.info["converged"] and not fem.result_.info["process_noise"]
    np.testing.assert_array_less(np.abs(fem.theta_ - ml.theta_), 0.01 * ml.std_)
    np.testing.assert_allclose(fem.std_, ml.std_, rtol=0.05)  # R estimated jointly: a little more uncertain
    # in calm air with the process noise free, F goes to ~0 and FEM stays ML within 0.1 std
    free = FEM(_off(navion)).fit(runs)
    np.testing.assert_array_less(np.abs(free.theta_ - ml.theta_), 0.1 * ml.std_)


LATERAL = """
name = "lateral, acceleration outputs"
states = { v = "m/s", p = "rad/s", r = "rad/s", phi = "rad" }
inputs = { da = "rad", dr = "rad" }
outputs = ["p_dot", "r_dot", "a_y", "p", "r"]
[output_defs]
a_y = { v_dot = 1.0, phi = -9.81, r = 50.0 }   # specific force: Y_v v + Y_dr dr
[free]
Y_v = -0.25
L_v = -0.05
L_p = -4.0
L_r = 0.5
L_da = 20.0
N_v = 0.03
N_p = -0.2
N_r = -0.6
N_dr = -3.0
Y_dr = 3.0
[fixed]
Y_phi = 9.81
Y_r = -50.0
phi_p = 1.0
[process_noise]
v = 0.2
[initial_state]
v = 0.0
p = 0.0
r = 0.0
phi = 0.0
[zero_shifts]
p = false
"""


@pytest.fixture(scope="module")
def lateral_runs():
    p = parse_profile(LATERAL)
    t = np.arange(0, 20, DT)
    u = np.zeros((len(t), 2))
    u[(t > 1) & (t < 2), 0], u[(t > 2) & (t < 3), 0] = 0.02, -0.02
    u[(t > 6) & (t < 8), 1], u[(t > 8) & (t < 10), 1] = 0.03, -0.03
    sigma = [0.5 / math.sqrt(DT), 0, 0, 0]  # F_v = 0.5 m/s / sqrt(s): side gusts
    noise = {"p_dot": 0.01, "r_dot": 0.005, "a_y": 0.05, "p": 0.002, "r": 0.001}
    runs = [simulate_run(LinearModel(p), t, u, noise=noise, process_noise=sigma, seed=s,
                         bias={"a_y": 0.1, "r": 0.005}) for s in (10, 11)]
    return p, runs


def test_lateral_accelerations_known_x0_and_no_zero_shift(lateral_runs):
    p, runs = lateral_runs
    truth = LinearModel(p).theta
    fem = FEM(_off(p, 1.15)).fit(runs)
    r = fem.result_
    assert r.converged
    # every derivative within 3 std and z^2 summed a chi^2 with 10 degrees of freedom below its
    # 99.9 % point (all ten within 2 std happens only in ~60 % of seeds for unbiased estimates: over
    # 20 seeds of this case the z's had means -0.4..0.43 and stds 0.84..1.13)
    z = (r.theta - truth) / r.std
    assert np.all(np.abs(z) < 3) and np.sum(z ** 2) < 29.6, dict(zip(r.names, z.round(2)))
    assert abs(r.info["process_noise"]["v"]["F"] - 0.5) < 3 * r.info["process_noise"]["v"]["std"]
    assert all(x0 == {"v": 0.0, "p": 0.0, "r": 0.0, "phi": 0.0} for x0 in r.info["initial_states"])
    assert all(b["p"] == 0.0 and s["p"] == math.inf for b, s in zip(r.info["zero_shifts"], r.info["zero_shift_std"]))
    shifts = r.info["zero_shifts"][0]
    assert abs(shifts["a_y"] - 0.1) < 3 * r.info["zero_shift_std"][0]["a_y"]


def test_cli_estimate_fem_with_known_x0(lateral_runs, tmp_path, capsys):
    p, runs = lateral_runs
    prof = (tmp_path / "lateral.toml")
    prof.write_text(LATERAL.replace("[initial_state]\nv = 0.0\n", "[initial_state]\n"))
    files = [run.to_csv(tmp_path / f"run{k}.csv") for k, run in enumerate(runs)]
    out = tmp_path / "out"
    proc = _in_process(["estimate", "--profile", prof, "--method", "fem", *files, "--out", out, "--x0", "v=0"], capsys)
    assert proc.returncode == 0, proc.stderr
    assert "FEM iteration 1: cost" in proc.stderr and "FEM identification" in proc.stdout
    result = json.loads((out / "result.json").read_text())
    assert result["method"] == "fem" and result["converged"]
    assert result["info"]["initial_states_fixed"] == ["p", "phi", "r", "v"]
    assert "unit white noise" in result["info"]["process_noise_convention"]
    assert set(result["info"]["process_noise"]) == {"v"} and result["info"]["process_noise"]["v"]["std"] > 0


def test_refusals(navion):
    assert estimator_class("fem") is FEM
    with pytest.raises(EstimationError, match="not a state"):
        FEM(navion, process_noise={"x": 1.0}).fit([])


def test_ml_on_turbulent_data_says_fem_is_the_estimator(navion):
    truth = LinearModel(navion)
    turbulent = ML(navion).fit(_runs(truth, F_TRUE, (5,), duration=20.0)).result_
    assert "--method fem" in turbulent.info["estimator_advice"] and "--method fem" in turbulent.summary()
    calm = ML(navion).fit(_runs(truth, {}, (5,), duration=20.0)).result_
    assert calm.info["estimator_advice"] is None
