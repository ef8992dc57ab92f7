"""FEM's coloured-innovation bounds against a first-principles dense sandwich.

A small pitch model in turbulence (process noise on u and q), one 20 s run, measurement noise
low-pass filtered (AR(1) pole 0.8 per sample) beside white noise. The innovations at the estimate
are an affine map ``nu = G z + const`` of the data (G: the steady-state filter's impulse response),
so their true covariance is ``G Sigma_z G^T`` with ``Sigma_z`` the data noise's (turbulence
response and measurement noise), known exactly here. The dense sandwich
``M^-1 (M - J^T W J + J^T W Sigma_nu W J) M^-1`` (J the innovation sensitivities of the
derivatives, initial states and zero shifts, W = I (x) S^-1, M FEM's information with the noise
variances' part in S) is what FEM's coloured bounds estimate from the innovations' own
autocorrelation; with white measurement noise the correction is ~1.
"""
import numpy as np
import pytest
from scipy import signal

from identify import LinearModel, Run, discretize
from identify.estimators.filter_error import FEM
from tests.identify.refine.test_refine import DT, N, PROFILE

F_TRUE = {"u": 0.007, "q": 0.014}  # m/s / sqrt(s), rad/s / sqrt(s): the refine tests' turbulence
WHITE, COLOURED, POLE = 0.001, 0.01, 0.8  # per output (u, q, theta are scaled below)
SCALE = np.array([1.0, 0.5, 0.5])


def _forward(Phi, In, Out, X):
    """``y_k = Out sum_{j<k} Phi^(k-1-j) In X_j`` for X (N, a, c): (N, b, c)."""
    x = np.zeros((Phi.shape[0], X.shape[2]))
    out = np.empty((len(X), Out.shape[0], X.shape[2]))
    for k in range(len(X)):
        out[k] = Out @ x
        x = Phi @ x + In @ X[k]
    return out


def _adjoint(Phi, In, Out, X):
    """The transpose of :func:`_forward`'s map applied to X (N, b, c): (N, a, c)."""
    lam = np.zeros((Phi.shape[0], X.shape[2]))
    out = np.empty((len(X), In.shape[1], X.shape[2]))
    for j in range(len(X) - 1, -1, -1):
        out[j] = In.T @ lam
        lam = Out.T @ X[j] + Phi.T @ lam
    return out


def _fit(pole, seed=3):
    profile = PROFILE
    model = LinearModel(profile)
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.choice([-1.0, 0.0, 1.0], size=N // 25 + 1), 25)[:N, None] * 0.05
    Phi, Gamma = discretize(model.A, model.B, DT)
    fem0 = FEM(profile, process_noise=F_TRUE)
    fem0._validate()
    Qd = fem0._problem([Run(np.arange(N) * DT, {"eta": u[:, 0], "u": np.zeros(N), "q": np.zeros(N),
                                                  "theta": np.zeros(N)})])[0]._noise_cov(
        model.A[None], np.array([list(F_TRUE.values())]))[1][0]
    Lq = np.linalg.cholesky(Qd + 1e-18 * np.eye(3))
    x, y = np.zeros(3), np.empty((N, 3))
    for k in range(N):
        y[k] = model.C @ x
        x = Phi @ x + Gamma @ u[k] + Lq @ rng.standard_normal(3)
    b_ar = [np.sqrt(1 - pole ** 2)]
    v = (WHITE * rng.standard_normal((N, 3)) +
         COLOURED * signal.lfilter(b_ar, [1.0, -pole], rng.standard_normal((N, 3)), axis=0)) * SCALE
    z = y + v
    run = Run(np.arange(N) * DT, {"eta": u[:, 0], **{c: z[:, i] for i, c in enumerate(("u", "q", "theta"))}})
    fem = FEM(profile, process_noise=F_TRUE, coloured=True).fit([run])

    # Sigma_z X: turbulence response (Tw Qd Tw^T) and measurement noise (white + AR(1) from rest)
    ar = signal.lfilter(b_ar, [1.0, -pole], np.eye(N), axis=0)  # (N, N): column j the response to an impulse at j
    Iw = np.eye(3)

    def sigma_z(X):
        turb = _forward(Phi, Iw, model.C, np.einsum("ab,kbc->kac", Qd, _adjoint(Phi, Iw, model.C, X)))
        flat = X.reshape(N, -1)
        meas = (WHITE ** 2 * flat + COLOURED ** 2 * (ar @ (ar.T @ flat))).reshape(X.shape) * SCALE[None, :, None] ** 2
        return turb + meas

    prob = fem.problem_
    ev = prob.evaluate(fem.beta_, jacobian=True, noise=True)
    Kp, C = ev.Kp, ev.model.C
    Abar = discretize(ev.model.A, ev.model.B, DT)[0] - Kp @ C  # the predictor's transition

    def G(X):
        return X - _forward(Abar, Kp, C, X)

    def Gt(X):
        return X - _adjoint(Abar, Kp, C, X)

    M, _ = prob.information(ev)
    Sinv = np.linalg.inv(ev.S)
    J = ev.dnu[..., 0].copy()  # (N, ny, k)
    J[:, :, prob.p:prob.G] = 0.0  # F and R: their information is taken as the Cramér-Rao one
    WJ = np.einsum("ab,kbc->kac", Sinv, J)
    meat = np.einsum("kai,kaj->ij", WJ, G(sigma_z(Gt(WJ))))
    B = M - np.einsum("kai,kaj->ij", J, WJ) + meat
    active = np.isfinite(np.r_[fem.result_.std, np.ones(prob.k - prob.p)]) & (np.diag(M) > 0)
    Mi = np.zeros_like(M)
    Mi[np.ix_(active, active)] = np.linalg.inv(M[np.ix_(active, active)])
    structural = np.r_[np.arange(prob.p), prob.G + np.arange(prob.n + prob.ny)]  # derivatives, x0, zero shifts
    dense = np.sqrt(np.diag(Mi @ B @ Mi))[structural]
    white = np.sqrt(np.diag(Mi))[structural]
    cov_c, _, _ = prob.coloured(ev, active)
    return np.sqrt(np.diag(cov_c))[structural], fem.result_.info["std_white"], dense, white


# structural unknowns in the order _fit returns them
X_U, M_Q, M_THETA, M_ETA, B_Q = 0, 1, 2, 3, 8


def test_coloured_bounds_match_the_dense_sandwich_with_the_true_noise_covariance():
    col, wht, dense, white = _fit(POLE)
    np.testing.assert_allclose(wht, white[:4], rtol=1e-6)  # the same information, dense
    # low-pass noise: a constant (q's zero shift) is ~7x less certain than white noise would say,
    # the mid-frequency derivatives a little more certain
    assert dense[B_Q] / white[B_Q] > 3
    assert 0.5 < col[B_Q] / dense[B_Q] < 2  # one 20 s run's innovations: the low frequencies are few
    mid = [M_Q, M_THETA, M_ETA]
    np.testing.assert_allclose(col[mid], dense[mid], rtol=0.25)
    # every structural unknown: the corrected bound no farther from the true one than the white
    # bound is, but for the scatter of its autocorrelation estimate (a factor 1.5)
    assert np.all(np.abs(np.log(col / dense)) <= np.abs(np.log(white / dense)) + np.log(1.5))


def test_white_measurement_noise_gives_a_factor_near_one():
    col, wht, dense, white = _fit(0.0)
    theta = slice(0, 4)
    np.testing.assert_allclose(dense[theta] / white[theta], 1.0, rtol=0.15)  # turbulence only: nearly white
    np.testing.assert_allclose(col[theta] / wht, 1.0, rtol=0.2)


def test_a_coloured_correction_that_blows_up_is_refused_and_said(monkeypatch):
    from identify import simulate_run
    from identify.estimators import filter_error
    profile = PROFILE
    rng = np.random.default_rng(0)
    t = np.arange(N) * DT
    u = np.repeat(rng.choice([-1.0, 0.0, 1.0], size=N // 25 + 1), 25)[:N] * 0.05
    runs = [simulate_run(LinearModel(profile), t, u[:, None], noise_fraction=0.01, seed=0,
                         process_noise=np.array([0.05, 0.1, 0.0]))]
    real = filter_error.FilterProblem.coloured

    def blown(self, ev, active):
        cov, acf, passes = real(self, ev, active)
        return cov * 1e48, acf, passes

    monkeypatch.setattr(filter_error.FilterProblem, "coloured", blown)
    with pytest.warns(UserWarning, match="coloured-innovation correction changed a standard error"):
        fem = FEM(profile, process_noise={"u": None, "q": None}, coloured=True).fit(runs)
    info = fem.result_.info
    assert "ill-conditioned" in info["coloured_failed"] and info["std_coloured"] is None
    np.testing.assert_array_equal(fem.std_, info["std_white"])
