"""FEM with declared turbulence: the corner estimated within its bound, the outputs the user sees
(summary, result.json, the fitted profile), the command line's --turbulence, refine carrying it."""
import json
import math
import warnings

import numpy as np
import pytest
import scipy.linalg

from identify import LinearModel, Run, load_profile
from identify.estimators.filter_error import FEM
from identify.model.profile import parse_profile
from identify.model.turbulence import with_turbulence
from tests.identify.test_cli import _in_process

DT = 0.02
CORNER, SIGMA_W = 1.5, 1.0  # rad/s, m/s: a first-order gust on w


def gusty_runs(profile, seeds, duration=30.0, corner=CORNER, sigma=SIGMA_W):
    """Runs of ``profile`` (states u, w, q, theta) with a first-order gust on w entering as a
    relative wind, built here by hand (not by identify.model.turbulence): [x; w_g] with
    ``dx/dt = A x + B u - A[:, w] w_g``, ``dw_g/dt = -corner w_g + sigma sqrt(2 corner) eta``."""
    tr = LinearModel(profile)
    n, m = tr.n_states, tr.n_inputs
    A = np.zeros((n + 1, n + 1))
    A[:n, :n], A[:n, n], A[n, n] = tr.A, -tr.A[:, profile.state_names.index("w")], -corner
    Bu = np.vstack([tr.B, np.zeros((1, m))])
    E = scipy.linalg.expm(np.block([[A, Bu], [np.zeros((m, n + 1 + m))]]) * DT)
    Phi, Gam = E[:n + 1, :n + 1], E[:n + 1, n + 1:]
    M = np.zeros((2 * n + 2, 2 * n + 2))
    M[:n + 1, :n + 1], M[n, 2 * n + 1], M[n + 1:, n + 1:] = -A, 2 * corner * sigma ** 2, A.T
    V = scipy.linalg.expm(M * DT)
    Q = V[n + 1:, n + 1:].T @ V[:n + 1, n + 1:]
    Qh = np.linalg.cholesky(0.5 * (Q + Q.T) + 1e-18 * np.eye(n + 1))
    t = np.arange(0, duration, DT)
    runs = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        u = np.zeros(len(t))
        for a, b, amp in ((1, 2.5, 0.02), (2.5, 4, -0.02), (4, 5, 0.02), (8, 12, 0.01)):
            u[(t >= a) & (t < b)] = amp
        x = np.zeros(n + 1)
        x[n] = sigma * rng.standard_normal()
        X = np.empty((len(t), n + 1))
        for k in range(len(t)):
            X[k] = x
            x = Phi @ x + Gam[:, 0] * u[k] + Qh @ rng.standard_normal(n + 1)
        y = X[:, :n] @ tr.C.T
        y += 0.02 * y.std(axis=0) * rng.standard_normal(y.shape)
        ch = {"delta_e": u, **{name: y[:, j] for j, name in enumerate(profile.outputs)}}
        runs.append(Run(t, ch, source=f"<gusty seed {seed}>"))
    return runs


@pytest.fixture(scope="module")
def navion():
    return load_profile("navion_cruise_long")


@pytest.fixture(scope="module")
def fitted(navion):
    runs = gusty_runs(navion, (1, 2))
    start = navion.with_values({k: v * 1.15 for k, v in navion.free.items()})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return FEM(with_turbulence(start, "w")).fit(runs), runs


def test_corner_and_derivatives_estimated_within_their_bounds(fitted, navion):
    fem, _ = fitted
    res = fem.result_
    assert res.names == navion.free_names  # the user's derivatives, not the gust model's
    z = (res.theta - LinearModel(navion).theta) / res.std
    assert np.all(np.abs(z) < 3.5), dict(zip(res.names, z.round(2)))
    gust = res.info["turbulence"]["gusts"]["w"]
    assert gust["corner_estimated"] and 0 < gust["corner_std"] < 0.5 * CORNER
    assert abs(gust["corner"] - CORNER) < 3 * gust["corner_std"], gust
    assert 0 < gust["intensity_std"] < 0.3 * SIGMA_W and abs(gust["intensity"] - SIGMA_W) < 3 * gust["intensity_std"]


def test_the_user_sees_the_turbulence_model_and_the_next_fit_starts_there(fitted):
    fem, _ = fitted
    res = fem.result_
    text = res.summary()
    assert "process noise: turbulence, first-order gust states w_g" in text
    assert "w      corner" in text and "intensity" in text
    data = json.loads(json.dumps(res.to_dict()))
    assert data["info"]["turbulence"]["gusts"]["w"]["corner"] == pytest.approx(res.info["turbulence"]["gusts"]["w"]["corner"])
    nxt = res.identified_profile()
    assert nxt.turbulence["states"] == ["w"] and nxt.turbulence["corner_start"]["w"] == pytest.approx(
        res.info["turbulence"]["gusts"]["w"]["corner"])
    assert parse_profile(nxt.to_toml()).turbulence == nxt.turbulence


def test_white_process_noise_is_said_too(navion):
    runs = gusty_runs(navion, (3,), duration=10.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = FEM(navion, max_iter=3, process_noise={"u": None, "w": None}).fit(runs).result_
    assert res.info["process_noise_model"].startswith("process noise: white, on the equations of u (F")
    assert "turbulence" not in res.info


def test_cli_turbulence_option_and_profile_table(navion, tmp_path, capsys):
    runs = gusty_runs(navion, (4,), duration=20.0)
    paths = [str(r.to_csv(tmp_path / f"run{k}.csv")) for k, r in enumerate(runs)]
    out = tmp_path / "out"
    proc = _in_process(["identify", "estimate", *paths, "--profile", "navion_cruise_long", "--method", "fem",
                        "--turbulence", "w", "--out", out][1:], capsys)
    assert proc.returncode == 0, proc.stderr
    assert "process noise: turbulence, first-order gust states w_g" in proc.stdout
    info = json.loads((out / "result.json").read_text())["info"]
    assert set(info["turbulence"]["gusts"]) == {"w"}
    again = parse_profile((out / "identified_profile.toml").read_text())
    assert again.turbulence["states"] == ["w"]
    bad = _in_process(["estimate", *paths, "--profile", "navion_cruise_long", "--method", "fem",
                       "--turbulence", "p,x", "--out", tmp_path / "bad"], capsys)
    assert bad.returncode == 2 and "x: expected distinct states" in bad.stderr and "Traceback" not in bad.stderr


def test_refine_fem_carries_the_declaration(navion, fitted):
    from identify.refine import Refine

    _, runs = fitted
    profile = with_turbulence(navion, "w")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = Refine(profile, estimator=FEM(profile), kinds=("delay",), max_steps=1).fit(runs)
    assert r.result_.info["turbulence"]["gusts"]["w"]["corner_estimated"]
    assert r.profile_.turbulence["states"] == ["w"]
    assert math.isfinite(r.result_.info["turbulence"]["gusts"]["w"]["corner"])


def test_diffuse_likelihood_term_and_its_exact_gradient(navion):
    """The turbulence fits integrate each run's initial states and zero shifts out (de Jong's
    diffuse likelihood): the cost gains 0.5 sum_r log det(H_r^T S^-1 H_r), and the gradient the
    solver steps on is that term's (central differences of the cost with and without it)."""
    from identify.estimators.filter_error import turbulence as seam

    runs = gusty_runs(navion, (5, 6), duration=8.0)
    declared = parse_profile(navion.to_toml() + '\n[turbulence]\nstates = ["w"]\nlikelihood = "diffuse"\n')
    plain = FEM(with_turbulence(navion, "w"))
    plain._validate()
    assert not seam.augmented_estimator(plain, runs).diffuse  # not the default
    fem = FEM(declared)
    fem._validate()
    est = seam.augmented_estimator(fem, fem.check_runs(runs))
    assert est.diffuse
    est._validate()
    prob, beta, active = est._problem(runs)
    on = np.array([active[prob.local_index[r][prob.G:]] for r in range(prob.n_runs)])
    prob.stationary = [prob.profile.state_names.index("w_g")]  # the gust's start: a stationary draw
    beta[prob.index["x0"][:, -1]] = [0.3, -0.2]

    def term(b):
        prob.diffuse = None
        plain = prob.evaluate(b).cost
        prob.diffuse = on
        return prob.evaluate(b).cost - plain

    prob.diffuse = on
    exact = prob.evaluate(beta, jacobian=True, noise=True).diffuse_grad
    assert abs(term(beta)) > 1  # a term that moves the fit
    for i in range(prob.G):
        h = 1e-4 * max(abs(beta[i]), 1e-3)
        up, down = beta.copy(), beta.copy()
        up[i] += h
        down[i] -= h
        fd = (term(up) - term(down)) / (2 * h)
        assert exact[i] == pytest.approx(fd, rel=2e-3, abs=1e-6 * np.abs(exact).max()), (i, exact[i], fd)


def test_nothing_declared_fits_gust_states_on_the_velocities(fitted, navion):
    # FEM's default (no [process_noise], no [turbulence]): gust states on the profile's u and w, said
    # and recorded as the default; the truth has no u gust, whose F goes to 0 with the corner held:
    # left out, so the fit is the declared w gust's
    fem, runs = fitted
    start = navion.with_values({k: v * 1.15 for k, v in navion.free.items()})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = FEM(start).fit(runs).result_
    info = res.info["turbulence"]
    assert info["declared"] is False and info["not_found"] == ["u"] and set(info["gusts"]) == {"w"}
    assert "the default (neither [turbulence] nor [process_noise] declared" in res.info["process_noise_model"]
    # the same optimum (the second fit started from another first fit's derivatives)
    np.testing.assert_array_less(np.abs(res.theta - fem.result_.theta), 0.01 * fem.result_.std)
    np.testing.assert_allclose(res.std, fem.result_.std, rtol=0.01)
    assert res.identified_profile().turbulence["states"] == ["w"]  # the next fit starts there


def test_an_estimated_corner_stays_positive_in_the_fit(navion):
    # white process noise on u and w (no gust in the truth's sense): the w gust's corner has little
    # to go on and, stepped as it stood, came out at -0.0034 rad/s (no stationary gust); stepped in
    # its logarithm it stays positive
    from tests.identify.estimators.test_filter_error import F_TRUE, _off, _runs

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = FEM(with_turbulence(_off(navion), "u,w")).fit(_runs(LinearModel(navion), F_TRUE, (0, 1))).result_
    corners = {s: g["corner"] for s, g in res.info["turbulence"]["gusts"].items()}
    assert all(c > 0 for c in corners.values()), corners
    assert not any(k.startswith("corner of") for k in res.info["not_determined"]), res.info["not_determined"]


def test_cli_process_noise_option_fits_the_white_model(navion, tmp_path, capsys):
    runs = gusty_runs(navion, (4,), duration=10.0)
    paths = [str(r.to_csv(tmp_path / f"run{k}.csv")) for k, r in enumerate(runs)]
    proc = _in_process(["estimate", *paths, "--profile", "navion_cruise_long", "--method", "fem", "--max-iter", "2",
                        "--process-noise", "u,w", "--out", tmp_path / "white"], capsys)
    assert proc.returncode == 0, proc.stderr
    info = json.loads((tmp_path / "white" / "result.json").read_text())["info"]
    assert info["process_noise_model"].startswith("process noise: white, on the equations of u (F")
    assert set(info["process_noise"]) == {"u", "w"} and "turbulence" not in info
    bad = _in_process(["estimate", *paths, "--profile", "navion_cruise_long", "--method", "ml",
                       "--process-noise", "u", "--out", tmp_path / "ml"], capsys)
    assert bad.returncode != 0 and "--process-noise does not apply to ml" in bad.stderr and "Traceback" not in bad.stderr
