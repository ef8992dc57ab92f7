"""ML's information matrix solved by block elimination of the segments' initial states, and the
coloured-residual bounds, against dense computations from first principles on short records."""
import math

import numpy as np
import pytest
from scipy.linalg import toeplitz
from scipy.signal import lfilter

from identify import simulate_run
from identify.estimators.output_error import OutputError

from .test_ml import grid, two_axis_inputs


def _problem(s61, segment, T=8.0, dt=0.1, estimate_x0=True, seed=1, tau=None):
    """An S 61 output-error problem (one run, 5 % noise, low-passed with time constant ``tau``
    samples if given) at a point 10 % off the truth."""
    t = grid(T, dt)
    run = simulate_run(s61, t, two_axis_inputs(t, 3.0))
    p = s61.profile
    z = run.matrix(list(p.outputs))
    w = np.random.default_rng(seed).normal(size=z.shape)
    if tau is not None:
        a = math.exp(-1 / tau)
        w = lfilter([1 - a], [1, -a], w, axis=0) / math.sqrt((1 - a) / (1 + a))
    z = z + 0.05 * z.std(axis=0) * w
    prob = OutputError(p, [run.matrix(p.input_names)], [z], dt, segment, estimate_x0=estimate_x0)
    beta = prob.initial_beta(s61.theta * 1.1)
    Wh = np.diag(1 / (0.05 * z.std(axis=0)))
    return prob, beta, Wh


@pytest.mark.parametrize("segment, estimate_x0", [(2.0, True), (math.inf, True), (2.0, False)])
def test_block_elimination_gives_the_dense_step_and_covariance(s61, segment, estimate_x0):
    """Multiple shooting (4 segments, 58 unknowns), the plain form and held initial states: the
    Schur-complement step (undamped and damped) and the covariance blocks equal the dense ones."""
    prob, beta, Wh = _problem(s61, segment, estimate_x0=estimate_x0)
    ev = prob.evaluate(beta)
    info, g = prob.information(ev, Wh)
    M, g_dense = prob.normal_equations(ev, Wh)
    np.testing.assert_allclose(g, g_dense)
    d = np.sqrt(np.diag(M))
    for lam in (0.0, 1e-3, 1.0):
        dense = np.linalg.solve(M + lam * np.diag(d ** 2), g)
        np.testing.assert_allclose(info.solve(g, lam), dense, rtol=1e-7, atol=1e-9 * np.abs(dense).max())
    # a Gauss-Newton step from beta lands on the same estimates
    np.testing.assert_allclose(beta + info.solve(g), beta + np.linalg.solve(M, g), rtol=1e-9, atol=1e-12)
    # holding the parameters: the nuisance-only step of the dense system restricted to them
    nuisance = np.arange(prob.n_beta) >= prob.p
    i = np.flatnonzero(nuisance)
    step = np.zeros(prob.n_beta)
    step[i] = np.linalg.solve(M[np.ix_(i, i)], g[i])
    np.testing.assert_allclose(info.solve(g, 0.0, nuisance), step, rtol=1e-7, atol=1e-9 * np.abs(step).max())
    cov, ill = info.covariance()
    assert not ill
    cov_dense = np.linalg.inv(M)
    np.testing.assert_allclose(cov.dense(), cov_dense, rtol=1e-6, atol=1e-9 * np.abs(cov_dense).max())
    # the sandwich with any B of the same (per-segment) structure
    rng = np.random.default_rng(0)
    k = prob.p + prob.n + prob.ny
    Bl = rng.normal(size=(prob.layout.n_segments, k, k))
    Bl = Bl @ Bl.transpose(0, 2, 1)
    Bl[:, prob.local_index.min(axis=0) < 0] = 0.0
    Bl[:, :, prob.local_index.min(axis=0) < 0] = 0.0
    B = np.zeros_like(M)
    for s in range(prob.layout.n_segments):
        keep = prob.local_index[s] >= 0
        idx = prob.local_index[s][keep]
        B[np.ix_(idx, idx)] += Bl[s][np.ix_(keep, keep)]
    ref = cov_dense @ B @ cov_dense
    np.testing.assert_allclose(info.sandwich(Bl).dense(), ref, rtol=1e-6, atol=1e-8 * np.abs(ref).max())


def _dense_coloured_std(prob, ev, Wh, cov, passes=300):
    """The coloured-residual standard errors from first principles, with dense matrices: the
    global whitened Jacobian of every segment and output, the Toeplitz matrix of the noise
    autocorrelation, and the fixed point rho = r + [2 tr(S_k H T) - tr(S_k H T H)] / N solved by
    plain iteration to machine precision."""
    lay, ny = prob.layout, prob.ny
    Jloc = prob.local_jacobian(ev, Wh)  # (S, L, ny, k)
    J = []  # per segment (l, ny, n_beta)
    for s in range(lay.n_segments):
        keep = prob.local_index[s] >= 0
        Js = np.zeros((lay.length[s], ny, prob.n_beta))
        Js[..., prob.local_index[s][keep]] = Jloc[s, :lay.length[s]][..., keep]
        J.append(Js)
    e = [(Wh @ ev.e)[:lay.length[s], :, s] for s in range(lay.n_segments)]
    N = float(prob.mask.sum())
    L = lay.L
    r = np.zeros((L, ny))
    for es in e:
        for k in range(len(es)):
            r[k] += np.sum(es[:len(es) - k] * es[k:], axis=0) / N
    rho = r.copy()
    rho[1:] = 0.0
    for _ in range(passes):
        B = sum(Js[:, y].T @ toeplitz(rho[:len(Js), y]) @ Js[:, y] for Js in J for y in range(ny))
        cov_c = cov @ B @ cov
        corr = np.zeros((L, ny))
        for Js in J:
            for y in range(ny):
                T = toeplitz(rho[:len(Js), y])
                HT = Js[:, y] @ cov @ Js[:, y].T @ T
                HTH = Js[:, y] @ cov_c @ Js[:, y].T
                for k in range(len(Js)):
                    corr[k, y] += (np.trace(HT, -k) + np.trace(HT, k)) - np.trace(HTH, -k)
        rho_new = r + corr / N
        if np.max(np.abs(rho_new - rho)) < 1e-14:
            break
        rho = rho_new
    return np.sqrt(np.diag(cov_c)[:prob.p])


def test_coloured_bounds_equal_the_dense_toeplitz_computation(s61):
    """Low-passed noise (time constant 3 samples), 4 shooting segments: the FFT, block-sandwich,
    preconditioned and accelerated computation gives the standard errors of the dense
    ``cov (sum J^T T J) cov`` at the fixed point: to 1e-6 when iterated to convergence, and within
    1.5 % with the default stopping rule (no standard error changes by more than 1 % in a pass;
    measured here: 0.8 % after 8 passes)."""
    prob, beta, Wh = _problem(s61, 2.0, T=8.0, dt=0.1, tau=3.0)
    ev = prob.evaluate(beta)
    info, _ = prob.information(ev, Wh)
    cov, _ = info.covariance()
    ref = _dense_coloured_std(prob, ev, Wh, cov.dense())
    white = np.sqrt(cov.diag()[:prob.p])
    assert np.mean(ref / white) > 1.3  # the noise is coloured: the correction matters here
    exact, _, passes = prob.coloured_information(ev, Wh, info, max_iter=60, tol=1e-10)
    np.testing.assert_allclose(np.sqrt(exact.diag()[:prob.p]), ref, rtol=1e-6)
    fast, _, passes = prob.coloured_information(ev, Wh, info)
    dev = np.abs(np.sqrt(fast.diag()[:prob.p]) / ref - 1)
    print(f"default stopping: {passes} passes, max deviation from the fixed point {dev.max():.2e}")
    assert dev.max() < 0.015


def test_long_record_paths_give_the_same_bounds(s61, monkeypatch):
    """The memory-bounded paths of a long record (sensitivities recomputed a group of segments at a
    time, the coloured correction's Jacobian rebuilt per group or per time block, its columns
    taken a chunk at a time, no spectra kept between passes) give the same information, step and
    coloured bounds as the held, cached ones."""
    import identify.estimators.coloured_bounds as cb
    import identify.estimators.output_error as oe

    for segment in (2.0, math.inf):
        prob, beta, Wh = _problem(s61, segment, tau=3.0)
        ev = prob.evaluate(beta)
        info, g = prob.information(ev, Wh)
        ref_step = info.solve(g, 1e-3)
        ref = np.sqrt(prob.coloured_information(ev, Wh, info, max_iter=60, tol=1e-10)[0].diag())
        with monkeypatch.context() as m:
            m.setattr(oe, "SENS_GROUP_FLOATS", 1)  # one segment per group
            m.setattr(oe, "BLOCK_FLOATS", 1)  # time blocks of 8 samples
            m.setattr(cb, "COLOUR_CACHE", 0)
            m.setattr(cb, "COLOUR_CHUNK_FLOATS", 2 * 81 * 8 * 5 if segment == math.inf else 10 ** 9)
            ev = prob.evaluate(beta)
            assert ev.held is None or prob.layout.n_segments == 1
            info, g = prob.information(ev, Wh)
            np.testing.assert_allclose(info.solve(g, 1e-3), ref_step, rtol=1e-9, atol=1e-12)
            got = np.sqrt(prob.coloured_information(ev, Wh, info, max_iter=60, tol=1e-10)[0].diag())
        np.testing.assert_allclose(got, ref, rtol=1e-8)
