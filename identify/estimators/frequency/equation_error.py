"""Frequency-domain equation error (Morelli & Klein): ``FDEE``, batch (``fit``) and streaming (``partial_fit``).

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

Streaming (Morelli, AIAA 99-4043): ``FDEE.partial_fit(t, x, u)`` adds samples to one growing
record's transform (one complex multiply-add per frequency and channel, :class:`FourierTransform`)
and :meth:`FDEE.solve` / :meth:`FDEE.step` re-solve whenever asked (about once a second in the
cockpit), giving a :class:`LiveEstimate`. The same samples through ``fit`` give the same numbers.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...data.runs import Run
from ...errors import EstimationError
from ...model.linear import LinearModel
from ..equation_error import Group, check_rank, EquationError, MeasuredRun
from ..result import IdentificationResult, insensitivity
from .base import FourierTransform, Transform, record_kernel

LIVE_BAND = (0.05, 1.5)  # Hz: the streamed record's band (the cockpit's), fixed before any sample
LIVE_N_FREQ = 60
DEFAULT_F_MAX = 2.0  # Hz: above it rotorcraft rigid-body models stop holding
MAX_FREQUENCIES = 200
SMOOTH_HALF_WIDTH = 3  # frequencies either side in the residual-spectrum estimate


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
            self._K = (record_kernel(self.d_vals, T)[self.d_idx].reshape(self.shape),
                       record_kernel(self.s_vals, T)[self.s_idx].reshape(self.shape))
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
            scale = check_rank(np.vstack([X.real, X.imag]), names)
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


# -- the estimator -------------------------------------------------------------------------------
class FDEE(EquationError):
    """Frequency-domain equation error over one or several runs (Morelli & Klein), or streamed.

    Options: ``band`` (Hz, default one cycle of the shortest run to min(2 Hz, 0.2 x sample rate);
    streamed: LIVE_BAND); ``n_freq`` (default: spacing half of 1/T, at most 200; streamed:
    LIVE_N_FREQ); ``held_inputs`` (inputs held over each sample, as simulations and the cockpit log
    have them; False for inputs sampled from continuous signals); ``bias`` (a zero shift per run and
    equation); ``coloured`` (standard errors corrected for coloured residuals, default True);
    ``reinit`` only for how ``result_.modelled`` is simulated. Every state must be measured; no
    derivative is needed (``jw X(w)`` stands for the transform of ``dx/dt``).

    ``fit(runs)`` estimates from whole runs (``result_``). ``partial_fit(t, x, u)`` adds samples of
    the states (n,) or (k, n) and inputs (m,) or (k, m) at times t (s) to one live record, whose
    frequencies ``omega_`` are fixed at the first call; ``solve()`` re-solves every equation group,
    ``step()`` only the next one in turn (to spread a re-solve over frames) and returns the
    :class:`LiveEstimate` when a round completes.
    """

    method = "fdee"
    weighs_prior = False  # its own regressions: the prior is combined with their estimate (base.fit)

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

    def _prepare(self, runs: list[Run]) -> list[MeasuredRun]:
        """The measured states and inputs, checked finite; unlike LS and IV no derivative."""
        return [self._measured(run) for run in runs]

    # batch ------------------------------------------------------------------------------------
    def _fit(self, runs: list[Run]) -> IdentificationResult:
        data = self._prepare(runs)
        dt = min(d.run.dt for d in data)
        omega = default_frequencies([d.run.duration for d in data], dt, self.band, self.n_freq)
        trs = [FourierTransform(omega, self.held_inputs).fit(d.run.time, d.x, d.u).transform() for d in data]
        groups = self._groups()
        solved = solve_groups(self.model_, groups, trs, omega, self.bias)
        failed = [s["error"] for s in solved.values() if "error" in s]
        if failed:
            raise EstimationError(f"FDEE over {omega[0] / 2 / np.pi:.3g}..{omega[-1] / 2 / np.pi:.3g} Hz: "
                                  f"{'; '.join(failed)}")
        theta, cov, cov_white, biases, rms = self._collect(groups, solved, len(data))
        info = {"band_hz": [float(omega[0] / 2 / np.pi), float(omega[-1] / 2 / np.pi)], "n_frequencies": len(omega),
                "held_inputs": self.held_inputs, "residual_rms_frequency_domain": rms,
                "derivatives": "not used: j w X(w) in the frequency domain",
                "frequency_domain": True}
        result = self._result(data, theta, cov, cov_white, biases, info)
        result.info["standard_errors"] = ("coloured-residual correction (smoothed residual spectrum, "
                                          "finite-record kernel)" if self.coloured else "white residuals")
        result.info["accuracy"] = result.accuracy()  # Cramér-Rao and insensitivity %, flagged
        return result

    def _collect(self, groups: list[Group], solved: dict, n_runs: int):
        """The groups' solutions placed into the full parameter vector and covariances."""
        m = self.model_
        p = len(m.names)
        theta, cov, cov_white = np.zeros(p), np.zeros((p, p)), np.zeros((p, p))
        biases, rms = np.zeros((n_runs, m.n_states)), {}
        for gi, g in enumerate(groups):
            s, idx = solved[gi], np.array(g.params)
            theta[idx] = s["theta"]
            cov[np.ix_(idx, idx)], cov_white[np.ix_(idx, idx)] = s["cov"], s["cov_white"]
            biases[:, g.equations] = s["biases"]
            rms.update({self.profile_.state_names[e]: v for e, v in zip(g.equations, s["residual_rms"])})
        return theta, cov, cov_white, biases, rms

    # streaming --------------------------------------------------------------------------------
    def partial_fit(self, t, x, u) -> "FDEE":
        """Add samples to the live record (see the class notes); the first call fixes the frequencies."""
        if getattr(self, "transform_", None) is None:
            self._validate()
            self.groups_ = self._groups()
            lo, hi = self.band or LIVE_BAND
            self.omega_ = 2 * np.pi * np.linspace(lo, hi, self.n_freq or LIVE_N_FREQ)
            self.transform_ = FourierTransform(self.omega_, self.held_inputs)
            self.solved_, self.next_group_ = {}, 0
        self.transform_.partial_fit(t, x, u)
        return self

    @property
    def n_samples(self) -> int:
        return 0 if getattr(self, "transform_", None) is None else self.transform_.n_samples

    def _solve_live(self, only) -> None:
        if self.n_samples == 0:
            raise EstimationError("FDEE: no samples streamed yet (call partial_fit first)")
        tr = self.transform_.transform()
        self.solved_.update(solve_groups(self.model_, self.groups_, [tr], self.omega_, self.bias, only,
                                         white=False))

    def solve(self) -> "LiveEstimate":
        """Re-solve every group of the streamed record now."""
        self._solve_live(None)
        self.next_group_ = 0
        return self.estimate()

    def step(self) -> "LiveEstimate | None":
        """Re-solve the next group; the estimate when this completes a round, else None."""
        if self.n_samples == 0 or self.transform_.T <= 0:
            return None
        self._solve_live([self.next_group_])
        self.next_group_ = (self.next_group_ + 1) % len(self.groups_)
        return self.estimate() if self.next_group_ == 0 else None

    def estimate(self) -> "LiveEstimate":
        """The live estimate from the groups solved so far (a priori values where none is)."""
        p = len(self.model_.names)
        theta, std, ins = self.model_.theta.copy(), np.full(p, np.nan), np.full(p, np.nan)
        errors = {}
        for gi, g in enumerate(self.groups_):
            r = self.solved_.get(gi)
            eq = ",".join(self.profile_.equation(self.profile_.state_names[e]) for e in g.equations)
            if r is None or "error" in r:
                errors[eq] = "not solved yet" if r is None else r["error"]
                continue
            theta[g.params] = r["theta"]
            std[g.params] = np.sqrt(np.maximum(np.diag(r["cov"]), 0))
            ins[g.params] = insensitivity(r["cov"])
        return LiveEstimate(self.transform_.T, theta, std, errors, ins)


@dataclass
class LiveEstimate:
    """One re-solve of the streamed estimate: at record time ``t`` (s), ``theta`` and ``std``
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
