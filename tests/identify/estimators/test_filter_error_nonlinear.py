"""The filter-error method on profiles with state-built terms (the extended Kalman filter): a
quadratic pitch damping M q|q| recovered under turbulence where output error is not, found by refine
on the innovations, equal to output error's maximum likelihood in calm air, and the command line."""
import json
import warnings
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import least_squares

from identify import ML, LinearModel
from identify.data.runs import Run
from identify.estimators.filter_error import FEM
from identify.estimators.prediction import fit_state_terms
from identify.model.pseudo_inputs import prepare
from identify.model.simulate import discretize
from identify.refine import Refine
from identify.refine.candidates import Nonlinear
from tests.identify.refine.test_refine import DT, N, PROFILE, excitation
from tests.identify.test_cli import _in_process

COEF = -20.0  # M_q_absq, 1/rad: quadratic pitch damping
TRUTH = np.array([-0.5, -2.0, -4.0, 5.0, COEF])  # X_u, M_q, M_theta, M_eta, M_q_absq
# turbulence: per-sample std of a white disturbance on the u and q equations (m/s^2, rad/s^2)
TURBULENCE = np.array([0.2, 0.4, 0.0])
NOISE = {"u": None, "q": None}  # FEM's process noise where the turbulence acts, started from the data


def nonlinear_profile(value=0.0):
    return Nonlinear("M", "q_absq", ("q",), "absq", "quadratic damping").profile(PROFILE, {"M_q_absq": value})


def simulate(seed: int, turbulence=TURBULENCE, coef: float = COEF) -> Run:
    """The pitch model with M += coef q|q|, the term held over each sample (the filter's own
    discretisation), white turbulence on the force and moment equations, 1 % white measurement noise."""
    model = LinearModel(PROFILE)
    Phi, Gamma = discretize(model.A, np.hstack([model.B, np.array([[0.0], [1.0], [0.0]]), np.eye(3)]), DT)
    u = excitation(seed)
    rng = np.random.default_rng(seed)
    w = rng.standard_normal((N, 3)) * turbulence
    x = np.zeros((N, 3))
    for k in range(N - 1):
        x[k + 1] = Phi @ x[k] + Gamma @ np.r_[u[k, 0], coef * x[k, 1] * abs(x[k, 1]), w[k]]
    channels = {"eta": u[:, 0]}
    for j, y in enumerate(("u", "q", "theta")):
        channels[y] = x[:, j] + 0.01 * np.std(x[:, j]) * rng.standard_normal(N)
    return Run(np.arange(N) * DT, channels, source=f"<q|q| truth {seed}>")


def test_fem_recovers_quadratic_damping_under_turbulence_where_ml_does_not():
    prof, runs = nonlinear_profile(), [simulate(1), simulate(2)]
    fem = FEM(prof, process_noise=NOISE).fit(runs).result_
    assert fem.converged and fem.names[-1] == "M_q_absq"
    z = (fem.theta - TRUTH) / fem.std
    assert abs(z[-1]) < 2 and np.all(np.abs(z) < 3), dict(zip(fem.names, z.round(2)))
    assert set(fem.info["process_noise"]) == {"u", "q"} and np.all(fem.info["diag_CK"] <= 1)
    # output error with the term on its own simulated states (as refine and the command line fit it)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ml = fit_state_terms(lambda p: ML(p), prof, prepare(prof, runs))[1]
    rel = lambda r: np.abs(r.theta - TRUTH) / np.abs(TRUTH)  # noqa: E731
    assert rel(ml)[-1] > 1.5 * rel(fem)[-1] and np.mean(rel(ml)) > 2 * np.mean(rel(fem)), (rel(ml), rel(fem))


def _output_error_reference(prof, runs, R):
    """The nonlinear output-error estimate, independently: scipy's least squares on the model
    simulated with the term on its own states, the residuals weighted by ``R``^-1/2, each run's
    initial state and zero shifts free."""
    model0, n_runs = LinearModel(prof), len(runs)
    w = 1 / np.sqrt(R)

    def residuals(beta):
        model = model0.with_theta(beta[:5])
        Phi, Gamma = discretize(model.A, model.B, DT)
        out = []
        for r, run in enumerate(runs):
            x0, b = beta[5 + 6 * r:8 + 6 * r], beta[8 + 6 * r:11 + 6 * r]
            x, y = x0.copy(), np.zeros((N, 3))
            for k in range(N):
                y[k] = x
                x = Phi @ x + Gamma @ np.r_[run["eta"][k], x[1] * abs(x[1])]
            out.append(((run.matrix(["u", "q", "theta"]) - y - b) * w).ravel())
        return np.concatenate(out)

    start = np.concatenate([model0.theta, np.zeros(6 * n_runs)])
    return least_squares(residuals, start, x_scale="jac", xtol=1e-12, ftol=1e-12).x[:5]


def test_without_process_noise_the_extended_filter_is_output_error_ml():
    prof, runs = nonlinear_profile(), [simulate(1, turbulence=0.0), simulate(2, turbulence=0.0)]
    fem = FEM(prof, process_noise={}).fit(runs).result_
    assert fem.converged and not fem.info["process_noise"]
    R = np.array([fem.info["measurement_noise"][y]["variance"] for y in ("u", "q", "theta")])
    reference = _output_error_reference(prof, runs, R)
    np.testing.assert_array_less(np.abs(fem.theta - reference), 0.1 * fem.std)
    assert abs(fem.theta[-1] - COEF) < 3 * fem.std[-1]


def test_refine_on_fem_finds_undeclared_quadratic_damping_under_turbulence():
    turbulence = TURBULENCE / 2
    # refine accepts an effect only where it lowers the held-out error beyond its noise: one 20 s
    # validation run shows the true q|q| at 1.8 sd of the paired test (bar 2.49) and it is refused;
    # three show it (measured; the power this costs is in the closing note of #29)
    fit = [simulate(1, turbulence), simulate(2, turbulence)]
    val = [simulate(s, turbulence) for s in (9, 10, 11)]
    r = Refine(PROFILE, estimator=FEM(PROFILE, process_noise=NOISE), kinds=("derivative", "nonlinear")
               ).fit(fit, validate=val)
    assert [(s.effect, s.target) for s in r.steps_] == [("nonlinear", "M:q_absq")], \
        [s.to_dict() for s in r.steps_ + r.rejected_]
    est = r.steps_[0].parameters["M_q_absq"]
    assert abs(est["value"] - COEF) < 2 * est["std"], est


def test_cli_estimate_fem_on_a_profile_with_a_state_built_term(tmp_path, capsys):
    profile = tmp_path / "pitch_qq.toml"  # process noise where the turbulence acts, F started near it
    profile.write_text(replace(nonlinear_profile(), process_noise={"u": 0.03, "q": 0.06}).to_toml())
    files = [simulate(s).to_csv(tmp_path / f"run{s}.csv") for s in (1, 2)]
    out = tmp_path / "out"
    proc = _in_process(["estimate", "--profile", profile, "--method", "fem", *files, "--out", out], capsys)
    assert proc.returncode == 0, proc.stderr
    assert "FEM identification" in proc.stdout and "M_q_absq" in proc.stdout
    result = json.loads((out / "result.json").read_text())
    assert result["method"] == "fem" and result["converged"]
    assert set(result["info"]["process_noise"]) == {"u", "q"}
    z = {k: (v["value"] - t) / v["std"] for (k, v), t in zip(result["parameters"].items(), TRUTH)}
    assert all(abs(v) < 3 for v in z.values()), z


@pytest.mark.parametrize("hold", ["held", "linear"])
def test_extended_filter_sensitivities_are_exact(hold):
    """A state times an input of non-zero mean (the gain from a linearisation that is not the linear
    part), runs of different lengths: the innovations' and S's derivatives equal central differences."""
    prof = Nonlinear("M", "q_x_eta", ("q", "eta"), "prod", "test").profile(PROFILE, {"M_q_x_eta": 3.0})
    runs = [r.with_channels({"eta": r["eta"] + 0.05}, input_hold=hold) for r in (simulate(1), simulate(2))]
    est = FEM(prof, process_noise=NOISE)
    est._validate()
    prob, beta, _ = est._problem(est.check_runs([runs[0], runs[1].slice(0, 15.0)]))
    assert np.any(prob.J0) and prob.hold == hold
    beta[prob.index["r"]] = 1e-4
    ev = prob.evaluate(beta, jacobian=True, noise=True)
    r = 1  # the shorter run: padded after its end
    for j, g in enumerate(prob.local_index[r]):
        h = 1e-6 * max(abs(beta[g]), 1e-2)
        up, down = beta.copy(), beta.copy()
        up[g] += h
        down[g] -= h
        hi, lo = prob.evaluate(up), prob.evaluate(down)
        num = (hi.nu[:, :, r] - lo.nu[:, :, r]) / (2 * h)
        np.testing.assert_allclose(ev.dnu[:, :, j, r], num, atol=1e-5 * np.abs(num).max() + 1e-12)
        if j < prob.G:
            np.testing.assert_allclose(ev.dS[j], (hi.S - lo.S) / (2 * h), atol=1e-5 * np.abs(hi.S).max())
