"""Frequency-domain equation error (Morelli & Klein): batch (``FDEE``) and recursive (``RecursiveFDEE``).

The state equations ``dx/dt = A x + B u + b`` (b a zero shift per run and equation), Fourier
transformed over a record ``[0, T]`` at frequencies ``w`` of a chosen band, read::

    jw X(w) + x(T) e^{-jwT} - x(0) = A X(w) + B U(w) + b (1 - e^{-jwT}) / (jw)

with ``X(w) = int_0^T x e^{-jwt} dt`` the finite Fourier transform (trapezoidal rule for the states;
for inputs held over each sample, as the cockpit's frame log and every simulation here treat them,
the exact integral of the held signal, which carries the hold's half-sample delay). The boundary
term makes the equation exact for records that do not start and end at rest. The equation is
linear in the parameters, row by row in frequency, so each state equation (or group tied by a
shared parameter, as in LS) is a complex least-squares regression solved as real normal equations
``Re(X^H X) theta = Re(X^H y)``. No simulation is needed, so an unstable model (the S 61 in hover)
is estimated as easily as a stable one, and no state derivative is differentiated: noise above the
band never enters.

Standard errors (Cramér-Rao bounds corrected for coloured residuals): the residual ``e(w)`` of each
run and equation is the transform of a time-domain residual with spectrum ``S(w)``, estimated by
smoothing ``|e(w)|^2 / T`` over neighbouring frequencies. Then ``E[e_k e_l^*] ~ sqrt(S_k S_l)
K(w_k - w_l)`` and ``E[e_k e_l] ~ sqrt(S_k S_l) K(w_k + w_l)`` with ``K(d) = int_0^T e^{-jdt} dt``
(the finite record's kernel: frequencies closer than ``1/T`` have correlated residuals), and the
covariance is the sandwich ``M^-1 1/2 Re(X^H V X + X^H V' conj(X)) M^-1``, ``M = Re(X^H X)``. The
white-residual bound (one flat spectrum per run and equation) is kept in ``info["std_white"]``.

The recursive version (Morelli, AIAA 99-4043) updates the transforms every sample, one complex
multiply-add per frequency and channel, and re-solves whenever asked (about once a second in the
cockpit); see :class:`RecursiveFDEE`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..data.runs import Run
from ..errors import EstimationError
from ..model.linear import LinearModel
from ..model.profile import Profile, load_profile
from .equation_error import Group, _check_rank, _EquationError, equation_groups
from .result import IdentificationResult, insensitivity

DEFAULT_F_MAX = 2.0  # Hz: above it rotorcraft rigid-body models stop holding
MAX_FREQUENCIES = 200
SMOOTH_HALF_WIDTH = 3  # frequencies either side in the residual-spectrum estimate


@dataclass
class Transform:
    """Finite Fourier transforms of one record at ``omega`` (rad/s): states ``X`` (nf, n), inputs
    ``U`` (nf, m) (units x s), boundary term ``end`` (nf, n) = ``x(T) e^{-jwT} - x(0)``, ``one``
    (nf,) the transform of 1 (the zero shift's regressor), record length ``T`` (s)."""

    X: np.ndarray
    U: np.ndarray
    end: np.ndarray
    one: np.ndarray
    T: float


def _kernel(d: np.ndarray, T: float) -> np.ndarray:
    """``int_0^T e^{-jdt} dt`` for an array of frequency differences d (rad/s)."""
    small = np.abs(d) * T < 1e-9
    with np.errstate(divide="ignore", invalid="ignore"):
        k = (1 - np.exp(-1j * d * T)) / (1j * d)
    return np.where(small, T + 0j, k)


def transform(t: np.ndarray, x: np.ndarray, u: np.ndarray, omega: np.ndarray, held_inputs: bool = True,
              chunk: int = 4096) -> Transform:
    """Transforms of states x (N, n) and inputs u (N, m) sampled at t (N,) (from t[0]), in chunks
    of samples so memory stays (chunk, nf)."""
    t = np.asarray(t, dtype=float) - t[0]
    N, T = len(t), float(t[-1])
    w_trap = np.concatenate([[(t[1] - t[0]) / 2], (t[2:] - t[:-2]) / 2, [(t[-1] - t[-2]) / 2]])
    X = np.zeros((len(omega), x.shape[1]), complex)
    U = np.zeros((len(omega), u.shape[1]), complex)
    for k0 in range(0, N, chunk):
        k1 = min(N, k0 + chunk + 1)  # one sample of overlap for the held inputs' intervals
        e = np.exp(-1j * np.outer(t[k0:k1], omega))  # (c, nf)
        own = slice(0, min(chunk, N - k0))
        X += e[own].T @ (x[k0:k0 + own.stop] * w_trap[k0:k0 + own.stop, None])
        if held_inputs:  # u[k] held over [t_k, t_k+1]: int = u_k (e_k - e_k+1) / (jw)
            diff = (e[:-1] - e[1:]) / (1j * omega)
            U += diff.T @ u[k0:k1 - 1]
        else:
            U += e[own].T @ (u[k0:k0 + own.stop] * w_trap[k0:k0 + own.stop, None])
    end = np.outer(np.exp(-1j * omega * T), x[-1]) - x[0]
    return Transform(X, U, end, _kernel(omega, T), T)


def default_frequencies(durations: list[float], dt: float, band: tuple[float, float] | None = None,
                        n_freq: int | None = None) -> np.ndarray:
    """Evenly spaced frequencies (rad/s) over ``band`` (Hz; default one cycle of the shortest run
    to min(2 Hz, 0.2 x the sample rate)), spaced half the longest run's resolution 1/T by default."""
    lo, hi = band or (1.0 / min(durations), min(DEFAULT_F_MAX, 0.2 / dt))
    if not 0 < lo < hi:
        raise EstimationError(f"frequency band {lo:g}..{hi:g} Hz is empty")
    if hi > 0.5 / dt:
        raise EstimationError(f"frequency band reaches {hi:g} Hz, above the Nyquist frequency {0.5 / dt:g} Hz")
    n = n_freq or int(min(MAX_FREQUENCIES, np.floor((hi - lo) * 2 * max(durations)) + 1))
    return 2 * np.pi * np.linspace(lo, hi, max(n, 2))


# -- the regression ------------------------------------------------------------------------------
def _blocks(model: LinearModel, g: Group, trs: list[Transform], omega: np.ndarray, bias: bool):
    """Complex regressor blocks (nf, q) and targets (nf,) per (run, equation) of a group."""
    ne, npar, nr = len(g.equations), len(g.params), len(trs)
    q = npar + (nr * ne if bias else 0)
    Xb, yb, Tb = [], [], []
    for r, tr in enumerate(trs):
        for k, e in enumerate(g.equations):
            block = np.zeros((len(omega), q), complex)
            # column j: (dA[j] X + dB[j] U)_e, only for the group's parameters
            block[:, :npar] = tr.X @ model.dA[g.params, e].T + tr.U @ model.dB[g.params, e].T
            if bias:
                block[:, npar + r * ne + k] = tr.one
            Xb.append(block)
            yb.append(1j * omega * tr.X[:, e] + tr.end[:, e] - tr.X @ model.A0[e] - tr.U @ model.B0[e])
            Tb.append(tr.T)
    return Xb, yb, Tb


def _smooth(p: np.ndarray, half: int = SMOOTH_HALF_WIDTH) -> np.ndarray:
    """Running mean over 2 half + 1 neighbours (fewer at the band's edges)."""
    c = np.concatenate([[0.0], np.cumsum(p)])
    i = np.arange(len(p))
    lo, hi = np.maximum(i - half, 0), np.minimum(i + half + 1, len(p))
    return (c[hi] - c[lo]) / (hi - lo)


class _Kernels:
    """``K(w_k - w_l)`` and ``K(w_k + w_l)`` (nf, nf) for record lengths T: evaluated on the few
    distinct sums and differences of the grid (2 nf - 1 for an even one) and spread by index."""

    def __init__(self, omega: np.ndarray):
        scale = max(float(np.abs(omega).max()), 1e-12)
        d, s = omega[:, None] - omega[None, :], omega[:, None] + omega[None, :]
        self.d_vals, self.d_idx = np.unique(np.round(d / scale, 12), return_inverse=True)
        self.s_vals, self.s_idx = np.unique(np.round(s / scale, 12), return_inverse=True)
        self.d_vals, self.s_vals = self.d_vals * scale, self.s_vals * scale
        self.shape = d.shape
        self._T, self._K = None, None

    def __call__(self, T: float):
        if T != self._T:
            self._T = T
            self._K = (_kernel(self.d_vals, T)[self.d_idx].reshape(self.shape),
                       _kernel(self.s_vals, T)[self.s_idx].reshape(self.shape))
        return self._K


_KERNELS: dict[bytes, _Kernels] = {}


def _kernels(omega: np.ndarray) -> _Kernels:
    key = omega.tobytes()
    if key not in _KERNELS:
        if len(_KERNELS) > 16:  # a handful of grids at a time; no unbounded growth
            _KERNELS.clear()
        _KERNELS[key] = _Kernels(omega)
    return _KERNELS[key]


def _middle(Xb, res, Tb, omega, coloured: bool) -> np.ndarray:
    """``sum_blocks 1/2 Re(X^H V X + X^H V' conj X)``: the residuals' share of the sandwich."""
    kernels = _kernels(omega)
    total = 0.0
    for X, e, T in zip(Xb, res, Tb):
        p = np.abs(e) ** 2 / T
        S = _smooth(p) if coloured else np.full_like(p, p.mean())
        root = np.sqrt(S)
        Kd, Ks = kernels(T)
        W = root[:, None] * X  # V = diag(root) K diag(root)
        total = total + 0.5 * np.real(W.conj().T @ (Kd @ W) + W.conj().T @ (Ks @ W.conj()))
    return total


def _independent(omega: np.ndarray, Tb: list[float]) -> float:
    """Independent real equations of the blocks: frequencies closer than 1/T are correlated, so a
    record of T s gives about (band width x T + 1) independent complex points, twice as many reals."""
    width = (omega[-1] - omega[0]) / (2 * np.pi)
    return float(sum(2 * min(len(omega), width * T + 1) for T in Tb))


def solve_groups(model: LinearModel, groups: list[Group], trs: list[Transform], omega: np.ndarray,
                 bias: bool = True, only: list[int] | None = None, white: bool = True):
    """Estimate the groups' parameters from transforms. Returns per group index a dict with
    ``theta`` (group parameters), ``cov``/``cov_white`` (their covariances), ``biases`` (runs, ne)
    and ``residual_rms`` per equation; a group the data cannot identify yet gets ``error``."""
    out = {}
    for gi, g in enumerate(groups):
        if only is not None and gi not in only:
            continue
        Xb, yb, Tb = _blocks(model, g, trs, omega, bias)
        X, y = np.vstack(Xb), np.concatenate(yb)
        names = [model.names[j] for j in g.params] + [f"zero shift {k}" for k in range(X.shape[1] - len(g.params))]
        try:
            scale = _check_rank(np.vstack([X.real, X.imag]), names)
        except EstimationError as exc:
            out[gi] = {"error": str(exc)}
            continue
        Xs = X / scale
        M = np.real(Xs.conj().T @ Xs)
        try:
            Minv = np.linalg.inv(M)
        except np.linalg.LinAlgError:
            out[gi] = {"error": f"not identifiable from these data (singular information): {', '.join(names)}"}
            continue
        est = Minv @ np.real(Xs.conj().T @ y) / scale
        res = [yy - XX @ est for XX, yy in zip(Xb, yb)]
        n_real, q = _independent(omega, Tb), X.shape[1]
        if n_real < q + 2:  # early in a live record: the residual would be fitted away
            out[gi] = {"error": f"record too short: about {n_real:.0f} independent real equations in the band "
                                f"for {q} unknowns ({', '.join(names[:len(g.params)])})"}
            continue
        dof = n_real / (n_real - q)
        covs = [dof * Minv @ _middle([b / scale for b in Xb], res, Tb, omega, c) @ Minv / np.outer(scale, scale)
                for c in ((True, False) if white else (True,))]
        covs.append(covs[0] if not white else covs[1])
        k, ne = len(g.params), len(g.equations)
        out[gi] = {"theta": est[:k], "cov": covs[0][:k, :k], "cov_white": covs[1][:k, :k],
                   "biases": est[k:].reshape(len(trs), ne) if bias else np.zeros((len(trs), ne)),
                   "residual_rms": [float(np.sqrt(np.mean(np.concatenate(res[i::ne]).__abs__() ** 2)))
                                    for i in range(ne)]}
    return out


# -- batch estimator -----------------------------------------------------------------------------
class FDEE(_EquationError):
    """Frequency-domain equation error over one or several runs (Morelli & Klein).

    Options: ``band`` (Hz, default one cycle of the shortest run to min(2 Hz, 0.2 x sample rate));
    ``n_freq`` (default: spacing half of 1/T, at most 200); ``held_inputs`` (inputs held over each
    sample, as simulations and the cockpit log have them; False for inputs sampled from continuous
    signals); ``bias`` (a zero shift per run and equation); ``coloured`` (standard errors corrected
    for coloured residuals, default True); ``reinit`` only for how ``result_.modelled`` is simulated.
    Every state must be measured; no derivative is needed.
    """

    method = "fdee"

    def __init__(self, profile, *, band: tuple[float, float] | None = None, n_freq: int | None = None,
                 held_inputs: bool = True, bias: bool = True, coloured: bool = True, reinit="auto"):
        super().__init__(profile, bias=bias, coloured=coloured, reinit=reinit)
        self.band, self.n_freq, self.held_inputs = band, n_freq, held_inputs

    def _validate(self) -> None:
        super()._validate()
        band = self.band
        if band is not None and not (len(band) == 2 and 0 < band[0] < band[1]):
            raise EstimationError(f"band must be (low, high) Hz with 0 < low < high, got {band!r}")
        if self.n_freq is not None and not (isinstance(self.n_freq, int) and self.n_freq >= 2):
            raise EstimationError(f"n_freq must be an integer of at least 2, got {self.n_freq!r}")

    def _fit(self, runs: list[Run]) -> IdentificationResult:
        data = self._prepare(runs)
        dt = min(d.run.dt for d in data)
        omega = default_frequencies([d.run.duration for d in data], dt, self.band, self.n_freq)
        trs = [transform(d.run.time, d.x, d.u, omega, self.held_inputs) for d in data]
        m = self.model_
        groups = self._groups()
        solved = solve_groups(m, groups, trs, omega, self.bias)
        failed = [s["error"] for s in solved.values() if "error" in s]
        if failed:
            raise EstimationError(f"FDEE over {omega[0] / 2 / np.pi:.3g}..{omega[-1] / 2 / np.pi:.3g} Hz: "
                                  f"{'; '.join(failed)}")
        p, n = len(m.names), m.n_states
        theta, cov, cov_white = np.zeros(p), np.zeros((p, p)), np.zeros((p, p))
        biases, rms = np.zeros((len(data), n)), {}
        for gi, g in enumerate(groups):
            s, idx = solved[gi], np.array(g.params)
            theta[idx] = s["theta"]
            cov[np.ix_(idx, idx)], cov_white[np.ix_(idx, idx)] = s["cov"], s["cov_white"]
            biases[:, g.equations] = s["biases"]
            rms.update({self.profile_.state_names[e]: v for e, v in zip(g.equations, s["residual_rms"])})
        info = {"band_hz": [float(omega[0] / 2 / np.pi), float(omega[-1] / 2 / np.pi)], "n_frequencies": len(omega),
                "held_inputs": self.held_inputs, "residual_rms_frequency_domain": rms}
        result = self._result(data, theta, cov, cov_white, biases, info)
        result.info["derivatives"] = "not used: j w X(w) in the frequency domain"
        result.info["standard_errors"] = ("coloured-residual correction (smoothed residual spectrum, "
                                          "finite-record kernel)" if self.coloured else "white residuals")
        result.info["frequency_domain"] = True
        result.info["accuracy"] = result.accuracy()  # Cramér-Rao and insensitivity %, flagged
        return result


# -- recursive estimator -------------------------------------------------------------------------
@dataclass
class LiveEstimate:
    """One re-solve of the recursive estimator: at record time ``t`` (s), ``theta`` and ``std``
    (p,) (nan where a group is not identifiable yet), ``errors`` {group equations: reason}."""

    t: float
    theta: np.ndarray
    std: np.ndarray
    errors: dict
    insensitivity: np.ndarray | None = None  # (p,) Tischler & Remple's, others known (nan: not solved)

    @property
    def relative_std(self) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return 100 * self.std / np.abs(self.theta)

    @property
    def relative_insensitivity(self) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return 100 * self.insensitivity / np.abs(self.theta)


class RecursiveFDEE:
    """Frequency-domain equation error with transforms updated sample by sample (Morelli 1999).

    ``update(t, x, u)`` adds one sample (states (n,), inputs (m,) at time t s): one complex
    multiply-add per frequency and channel, vectorised over both; ``solve()`` re-solves every
    equation group now, ``step()`` only the next one in turn (to spread a re-solve over frames),
    returning the estimate when a full round has completed. Frequencies: ``band`` (Hz) with
    ``n_freq`` points, fixed for the whole record. Inputs are taken as held over each sample.
    """

    def __init__(self, profile: Profile | str, band: tuple[float, float] = (0.05, 1.5), n_freq: int = 60,
                 bias: bool = True):
        self.profile = profile if isinstance(profile, Profile) else load_profile(profile)
        if not (len(band) == 2 and 0 < band[0] < band[1]) or n_freq < 2:
            raise EstimationError(f"band must be (low, high) Hz with 0 < low < high and n_freq >= 2")
        self.model = LinearModel(self.profile)
        self.groups = equation_groups(self.model)
        covered = {j for g in self.groups for j in g.params}
        if len(covered) < len(self.model.names):
            raise EstimationError("some parameters act only on the output equation: equation error cannot "
                                  "estimate them")
        self.omega = 2 * np.pi * np.linspace(band[0], band[1], n_freq)
        self.bias = bias
        n, m = self.model.n_states, self.model.n_inputs
        self._X = np.zeros((n_freq, n), complex)
        self._U = np.zeros((n_freq, m), complex)
        self._t0 = None
        self._prev = None  # (t, e (nf,), x e (nf, n), u (m,))
        self._x0 = None
        self._inv_jw = 1 / (1j * self.omega)
        self._results: dict[int, dict] = {}
        self._next = 0
        self.n_samples = 0

    def update(self, t: float, x, u) -> None:
        x, u = np.asarray(x, dtype=float), np.asarray(u, dtype=float)
        if self._t0 is None:
            self._t0, self._x0 = t, x.copy()
        tau = t - self._t0
        e = np.exp(-1j * self.omega * tau)
        xe = e[:, None] * x  # the multiply: one per frequency and state
        if self._prev is not None:
            tp, ep, xep, up = self._prev
            dt = tau - tp
            if dt <= 0:
                return  # a repeated time stamp adds nothing
            self._X += 0.5 * dt * (xep + xe)  # the add (trapezoid)
            self._U += ((ep - e) * self._inv_jw)[:, None] * up  # held input over [tp, tau]
        self._prev = (tau, e, xe, u)
        self._x_last = x
        self.n_samples += 1

    def transform(self) -> Transform:
        if self._prev is None:
            raise EstimationError("no samples yet")
        T = self._prev[0]
        return Transform(self._X.copy(), self._U.copy(), self._prev[2] - self._x0, _kernel(self.omega, T), T)

    def _solve(self, only) -> None:
        tr = self.transform()
        self._results.update(solve_groups(self.model, self.groups, [tr], self.omega, self.bias, only, white=False))

    def solve(self) -> LiveEstimate:
        """Re-solve every group now."""
        self._solve(None)
        self._next = 0
        return self.estimate()

    def step(self) -> LiveEstimate | None:
        """Re-solve the next group; the estimate when this completes a round, else None."""
        if self._prev is None or self._prev[0] <= 0:
            return None
        self._solve([self._next])
        self._next = (self._next + 1) % len(self.groups)
        return self.estimate() if self._next == 0 else None

    def estimate(self) -> LiveEstimate:
        p = len(self.model.names)
        theta, std, ins = self.model.theta.copy(), np.full(p, np.nan), np.full(p, np.nan)
        errors = {}
        for gi, g in enumerate(self.groups):
            r = self._results.get(gi)
            eq = ",".join(self.profile.equation(self.profile.state_names[e]) for e in g.equations)
            if r is None or "error" in r:
                errors[eq] = "not solved yet" if r is None else r["error"]
                continue
            theta[g.params] = r["theta"]
            std[g.params] = np.sqrt(np.maximum(np.diag(r["cov"]), 0))
            ins[g.params] = insensitivity(r["cov"])
        return LiveEstimate(self._prev[0] if self._prev else 0.0, theta, std, errors, ins)

