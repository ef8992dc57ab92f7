"""Transfer-function and low-order equivalent system (LOES) fits to one frequency response (NAVFIT-like).

:func:`fit_transfer_function` fits ``H(s) = (b_m s^m + ... + b_0) / (s^n + a_{n-1} s^{n-1} + ... + a_0)
e^{-tau s}`` of chosen orders ``m``, ``n`` (an optional equivalent delay ``tau``) to a measured
response ``H(omega)`` by Tischler's cost::

    J = 20 / n_w sum W_gamma [ (|H_m|dB - |H|dB)^2 + 0.01745 (phase_m - phase)^2 (deg) ],
    W_gamma = (1.58 (1 - exp(-gamma^2)))^2

over the frequencies with an estimate and coherence >= 0.6 (Tischler & Remple; J <= 100 a good
fit, <= 50 excellent). Start: Levy's linearised complex least squares (``a`` and ``b`` from
``H D = N``) for each delay of a grid, then ``scipy.optimize.least_squares`` on J with bounds (the
delay within ``tau_bounds``, coefficients within ``coef_bounds`` when given).

Standard errors (:attr:`TransferFunctionFit.std`): the Gauss-Newton covariance of the weighted
residuals scaled by the residual variance (``J`` per degree of freedom), the usual estimate when
the per-point errors are not known; Cramér-Rao % and insensitivity % per parameter follow
(CIFER's gates CR <= 20 %, insensitivity <= 10 %). Adjacent frequency points of a composite
response are correlated (closer than a window's resolution), so these bounds are optimistic by
roughly the square root of the points per resolution cell.

:func:`short_period` reads a second-order denominator as the short-period mode (omega_sp, zeta_sp)
with the equivalent delay tau_e, and :func:`mil1797_short_period_level` grades them by
MIL-STD-1797A: damping ratio and equivalent delay, and, given n/alpha (g/rad), the control
anticipation parameter CAP = omega_sp^2 / (n/alpha) and (category A) the omega_sp minimum; the
sources of each limit are in the notes above :data:`MIL1797_ZETA`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from .statespace import gates

MIN_COHERENCE = 0.6
W_GAIN, W_PHASE = 1.0, 0.01745
DB = 20 / np.log(10)


def coherence_weight(coherence: np.ndarray) -> np.ndarray:
    """Tischler's W_gamma = (1.58 (1 - exp(-gamma^2)))^2 (about 1 at coherence 1); ``coherence`` is
    gamma^2, as every coherence here."""
    return (1.58 * (1 - np.exp(-np.asarray(coherence)))) ** 2


@dataclass
class TransferFunctionFit:
    """A fitted ``num/den e^{-tau s}``: ``num`` (m+1,) and ``den`` (n+1,) descending powers of s
    (``den[0] = 1``), ``tau`` s; ``J`` Tischler's cost over ``n_points`` coherent frequencies;
    ``names``/``theta``/``std`` the free parameters (coefficients, then tau) with standard errors."""

    num: np.ndarray
    den: np.ndarray
    tau: float
    J: float
    n_points: int
    names: list[str]
    theta: np.ndarray
    std: np.ndarray
    insensitivity: np.ndarray
    at_bound: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def response(self, omega: np.ndarray) -> np.ndarray:
        s = 1j * np.asarray(omega, dtype=float)
        return np.polyval(self.num, s) / np.polyval(self.den, s) * np.exp(-self.tau * s)

    @property
    def poles(self) -> np.ndarray:
        return np.roots(self.den)

    @property
    def zeros(self) -> np.ndarray:
        return np.roots(self.num) if len(self.num) > 1 else np.array([])

    def accuracy(self) -> dict[str, dict]:
        """Cramér-Rao % and insensitivity % per parameter with the gates each exceeds."""
        return gates(self.names, self.theta, self.std, self.insensitivity)

    def summary(self) -> str:
        lines = [f"transfer function: ({_poly(self.num)}) / ({_poly(self.den)})"
                 + (f" e^(-{_shown(self.tau)} s)" if "tau" in self.names else ""),
                 f"J = {self.J:.1f} over {self.n_points} coherent frequencies ("
                 + ("fits: J <= 100)" if self.J <= 100 else "does NOT fit: J > 100)"),
                 f"{'parameter':<10}{'estimate':>12}{'std':>11}{'CR %':>8}{'insens. %':>10}  flag"]
        for n, v, s in zip(self.names, self.theta, self.std):
            a = self.accuracy()[n]
            why = undetermined(v, s, n in self.at_bound)
            if why:  # no digits of nothing: a value at its bound or smaller than its standard error
                lines.append(f"{n:<10}{_shown(v):>12}  not determined ({why})")
                continue
            lines.append(f"{n:<10}{v:12.5g}{s:11.3g}{a['cramer_rao_pct']:8.3g}{a['insensitivity_pct']:10.3g}  "
                         + ", ".join(a["over_gates"]))
        for p in _unique_poles(self.poles):
            if abs(p.imag) > 0:
                wn = abs(p)
                lines.append(f"pole pair: omega {wn:.4g} rad/s, zeta {-p.real / wn:.4g}")
            else:
                lines.append(f"pole: {p.real:.4g} 1/s")
        return "\n".join(lines + self.notes)



def undetermined(value: float, std: float, at_bound: bool = False) -> str:
    """Why a fitted figure is not determined ("" if it is): at its bound, a standard error that is
    not finite, or one larger than the value itself."""
    if at_bound:
        return f"at its bound {_shown(value)}"
    if not np.isfinite(std):
        return "standard error not finite"
    if std > abs(value):
        return f"standard error {std:.2g} larger than the value"
    return ""


def _shown(value: float) -> str:
    """A value at a bound as read: 0 rather than 1e-11 of optimiser residue."""
    return "0" if abs(value) < 1e-9 else f"{value:.4g}"


def _poly(c: np.ndarray) -> str:
    n = len(c) - 1
    return " + ".join(f"{v:.4g}" + (f" s^{n - k}" if n - k > 1 else " s" if n - k == 1 else "")
                      for k, v in enumerate(c))


def _unique_poles(p: np.ndarray) -> list[complex]:
    return [z for z in p if z.imag >= 0]


def tischler_residuals(Hm: np.ndarray, Hd: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Residual vector r with ``sum r^2 = J`` (Tischler's cost): per frequency the weighted dB and
    deg errors. ``weight`` (n,) is W_gamma; the phase error is wrapped to (-180, 180]."""
    n = len(Hd)
    scale = np.sqrt(20 / n * weight)
    mag = DB * (np.log(np.abs(Hm)) - np.log(np.abs(Hd)))
    phase = np.degrees(np.angle(Hm / Hd))
    return np.concatenate([scale * np.sqrt(W_GAIN) * mag, scale * np.sqrt(W_PHASE) * phase])


def fit_transfer_function(omega: np.ndarray, H: np.ndarray, coherence: np.ndarray | None = None, *,
                          n_num: int = 0, n_den: int = 2, delay: bool = True,
                          tau_bounds: tuple[float, float] = (0.0, 0.5),
                          coef_bounds: dict[str, tuple[float, float]] | None = None,
                          min_coherence: float = MIN_COHERENCE,
                          omega_range: tuple[float, float] | None = None) -> TransferFunctionFit:
    """Fit ``num(s)/den(s) e^{-tau s}`` (orders ``n_num``, ``n_den``; ``den`` monic) to ``H`` (nf,)
    at ``omega`` (nf,) rad/s by Tischler's cost J (see the module notes).

    ``coherence`` (nf,), default 1; ``omega_range`` (rad/s) limits the fitted band (LOES are fitted
    over 0.1..10 rad/s in MIL-STD-1797A); ``coef_bounds`` {name: (lo, hi)} bounds coefficients named
    ``b0..b_m`` (numerator, b_k multiplies s^k) and ``a0..a_{n-1}``; the delay lies in ``tau_bounds``.
    """
    omega = np.asarray(omega, dtype=float)
    H = np.asarray(H, dtype=complex)
    coh = np.ones(omega.shape) if coherence is None else np.asarray(coherence, dtype=float)
    use = np.isfinite(H) & (np.abs(H) > 0) & (coh >= min_coherence)
    if omega_range is not None:
        use &= (omega >= omega_range[0]) & (omega <= omega_range[1])
    n_par = n_num + 1 + n_den + int(delay)
    if use.sum() <= n_par / 2:
        raise ValueError(f"transfer-function fit: {int(use.sum())} coherent frequencies for {n_par} parameters")
    w, h, wt = omega[use], H[use], coherence_weight(coh[use])
    names = [f"b{k}" for k in range(n_num, -1, -1)] + [f"a{k}" for k in range(n_den - 1, -1, -1)] + \
        (["tau"] if delay else [])
    lo, hi = np.full(n_par, -np.inf), np.full(n_par, np.inf)
    if delay:
        lo[-1], hi[-1] = tau_bounds
    for name, (a, b) in (coef_bounds or {}).items():
        if name not in names:
            raise ValueError(f"coef_bounds names no parameter '{name}' (parameters: {', '.join(names)})")
        lo[names.index(name)], hi[names.index(name)] = a, b

    def unpack(x):
        num = x[:n_num + 1]
        den = np.concatenate([[1.0], x[n_num + 1:n_num + 1 + n_den]])
        return num, den, (x[-1] if delay else 0.0)

    def residuals(x):
        num, den, tau = unpack(x)
        s = 1j * w
        return tischler_residuals(np.polyval(num, s) / np.polyval(den, s) * np.exp(-tau * s), h, wt)

    best = None
    taus = np.linspace(max(tau_bounds[0], 0.0), tau_bounds[1], 11) if delay else [0.0]
    for tau0 in taus:
        x0 = np.concatenate([*_levy(w, h * np.exp(1j * w * tau0), wt, n_num, n_den)] + ([[tau0]] if delay else []))
        x0 = _inside(x0, lo, hi)
        try:
            sol = least_squares(residuals, x0, bounds=(lo, hi), x_scale="jac", method="trf",
                                xtol=1e-14, ftol=1e-14, gtol=1e-14, max_nfev=2000)
        except ValueError:
            continue
        if best is None or sol.cost < best.cost:
            best = sol
    if best is None:
        raise ValueError("transfer-function fit: no start converged")
    num, den, tau = unpack(best.x)
    J = float(2 * best.cost)
    std, ins = _bounds(best.jac, J, len(best.fun), n_par)
    at_bound = [n for n, x, a, b in zip(names, best.x, lo, hi) if np.isclose(x, a) or np.isclose(x, b)]
    notes = [] if best.success else [f"optimiser stopped: {best.message}"]
    if at_bound:
        notes.append(f"at a bound: {', '.join(at_bound)} (its standard error assumes the bound is not active)")
    return TransferFunctionFit(num, den, float(tau), J, int(use.sum()), names, best.x.copy(), std, ins,
                               at_bound, notes)


def _inside(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """x moved strictly inside finite bounds (least_squares needs an interior start)."""
    margin = 1e-9 * (1 + np.abs(x))
    x = np.where(np.isfinite(lo), np.maximum(x, np.where(np.isfinite(lo), lo, 0) + margin), x)
    return np.where(np.isfinite(hi), np.minimum(x, np.where(np.isfinite(hi), hi, 0) - margin), x)


def _levy(w: np.ndarray, h: np.ndarray, wt: np.ndarray, n_num: int, n_den: int):
    """Levy's linearised start: minimise |N(jw) - H D(jw)|^2 (weighted) for b (m+1,) and a (n,)."""
    s = 1j * w
    cols = [s ** k for k in range(n_num, -1, -1)] + [-h * s ** k for k in range(n_den - 1, -1, -1)]
    M = np.column_stack(cols) * np.sqrt(wt)[:, None]
    rhs = h * s ** n_den * np.sqrt(wt)
    # rows scaled by |s^n| so high frequencies do not dominate the linearised fit
    scale = 1 / np.maximum(np.abs(s) ** n_den, 1e-12)
    A = np.vstack([(M * scale[:, None]).real, (M * scale[:, None]).imag])
    b = np.concatenate([(rhs * scale).real, (rhs * scale).imag])
    x = np.linalg.lstsq(A, b, rcond=None)[0]
    return x[:n_num + 1], x[n_num + 1:]


def _bounds(jac: np.ndarray, J: float, n_res: int, n_par: int) -> tuple[np.ndarray, np.ndarray]:
    """Standard errors and insensitivities of least-squares parameters scaled by the residual variance."""
    dof = max(n_res - n_par, 1)
    s2 = J / dof
    F = jac.T @ jac / s2
    try:
        cov = np.linalg.inv(F)
    except np.linalg.LinAlgError:
        cov = np.linalg.pinv(F)
    with np.errstate(divide="ignore", invalid="ignore"):
        std = np.sqrt(np.maximum(np.diag(cov), 0.0))
        ins = 1 / np.sqrt(np.maximum(np.diag(F), 0.0))
    return std, ins


# -- short-period LOES and MIL-STD-1797A ---------------------------------------------------------
# Limits of MIL-STD-1797A's short-period requirements (Appendix A, para. 4.2.1.2), read from two
# public MATLAB encodings (facts only, no code taken):
#   [SIDPAC]  E. A. Morelli's SIDPAC milstd.m ("data in MIL-STD 1797A", pitch-rate LOES; names no
#             category): zeta 0.35-1.30 / 0.25-2.00 / >= 0.15, omega_sp >= 1.0 / 0.6 rad/s,
#             tau_e 0.10 / 0.20 / 0.25 s (its Level 3 zeta cap of 10 is a plot limit).
#   [Regan]   C. Regan's CapCrit.m and ShortPeriodCrit.m (2006, citing MIL-STD-1797A Appendix A
#             para. 4.2.1.2 Section A; the author's own comment: "TODO: Check these values"): damping x
#             CAP boxes per category A / B / C (below), no Level 3 CAP limit, and (category A only)
#             omega_sp >= 1.0 / 0.6 rad/s.
# Which row is checked against which source: MIL1797_SOURCES, the one place. Disagreement: category
# B's Level 3 damping minimum is 0.10 in [Regan] but 0.15 in MIL-F-8785C's table as remembered (0.15
# for every category); 0.15, the stricter, is kept and a level that depends on it says why.
# flight-phase category -> Level -> (zeta_min, zeta_max)
MIL1797_ZETA = {"A": ((0.35, 1.30), (0.25, 2.00), (0.15, np.inf)),
                "B": ((0.30, 2.00), (0.20, 2.00), (0.15, np.inf)),
                "C": ((0.35, 1.30), (0.25, 2.00), (0.15, np.inf))}
# flight-phase category -> (Level 1 (CAP_min, CAP_max), Level 2 (...)), CAP = omega_sp^2 / (n/alpha) in
# 1/(g s^2); outside Level 2: Level 3 (no Level 3 CAP limit in the sources)
MIL1797_CAP = {"A": ((0.28, 3.6), (0.16, 10.0)),
               "B": ((0.085, 3.6), (0.038, 10.0)),
               "C": ((0.16, 3.6), (0.05, 10.0))}
# flight-phase category -> omega_sp minimum (rad/s) for Level 1, Level 2; only where a source gives it
MIL1797_OMEGA_MIN = {"A": (1.0, 0.6)}
MIL1797_TAU = (0.10, 0.20, 0.25)  # equivalent delay limit per Level (s)
MIL1797_SOURCES = {
    "zeta A": "SIDPAC, Regan",
    "zeta B Levels 1-2": "Regan (agrees with the earlier from-memory row)",
    "zeta B Level 3": "UNVERIFIED: 0.10 in Regan, 0.15 in MIL-F-8785C from memory; 0.15 kept",
    "zeta C": "Regan (agrees with the earlier from-memory row)",
    "CAP A, B, C": "Regan (CapCrit; category A's CAP lines also ShortPeriodCrit's omega vs n/alpha corners)",
    "omega_sp minimum A": "SIDPAC, Regan",
    "tau_e": "SIDPAC",
}
# (category, Level) damping limits the sources disagree on: (the lower value, the kept value, why)
MIL1797_UNVERIFIED = {("B", 3): (0.10, 0.15, "the sources disagree: 0.10 in Regan's MIL-STD-1797A encoding, "
                                             "0.15 in MIL-F-8785C from memory")}


@dataclass
class ShortPeriod:
    """Short-period LOES figures: ``omega`` rad/s, ``zeta``, ``tau_e`` s with standard errors,
    the MIL-STD-1797A level (damping, delay and, with ``n_alpha`` g/rad, CAP and the frequency
    minimum; None if not determined) and the fit."""

    omega: float
    zeta: float
    tau_e: float
    std: dict[str, float]
    level: int | None
    level_reasons: list[str]
    fit: TransferFunctionFit
    n_alpha: float | None = None

    @property
    def cap(self) -> float:
        """Control anticipation parameter omega_sp^2 / (n/alpha), 1/(g s^2); NaN without n/alpha."""
        return float(self.omega ** 2 / self.n_alpha) if self.n_alpha is not None else float("nan")

    def lines(self) -> list[str]:
        s = self.std
        if not np.isfinite(self.omega):
            return [f"short period: not determined (the LOES denominator s^2 + {self.fit.den[1]:.4g} s + "
                    f"{self.fit.den[2]:.4g} has no stable pair; LOES J {self.fit.J:.1f})"]
        cap_text = "" if self.n_alpha is None else \
            f", CAP {_pm(self.cap, 2 * s['omega'] / self.omega * self.cap, '1/(g s^2)')} at n/alpha {self.n_alpha:g} g/rad"
        if "tau" not in self.fit.names:
            tau = "no delay fitted"
        elif "tau" in self.fit.at_bound and abs(self.tau_e) < 1e-9:  # at its lower bound: only an upper limit
            tau = f"at its bound 0 (not determined; below {2 * s['tau_e']:.2g} s at 2 sigma)"
        else:
            tau = _pm(self.tau_e, s["tau_e"], "s", "tau" in self.fit.at_bound)
        return [f"short period: omega_sp {_pm(self.omega, s['omega'], 'rad/s')}, zeta_sp {_pm(self.zeta, s['zeta'])}, "
                f"tau_e {tau}{cap_text} (LOES J {self.fit.J:.1f})",
                f"MIL-STD-1797A level: {self.level if self.level else 'not determined'} "
                f"({'; '.join(self.level_reasons)})"]


def short_period(fit: TransferFunctionFit, category: str = "A", n_alpha: float | None = None) -> ShortPeriod:
    """The short-period mode of a LOES fit with a second-order denominator (``s^2 + a1 s + a0``):
    omega = sqrt(a0), zeta = a1 / (2 omega), their standard errors by first-order propagation;
    ``n_alpha`` (g/rad, optional): the normal load factor per angle of attack, for CAP."""
    if len(fit.den) != 3:
        raise ValueError("short period: the LOES denominator must be of second order")
    a1, a0 = fit.den[1], fit.den[2]
    omega = float(np.sqrt(a0)) if a0 > 0 else float("nan")
    zeta = float(a1 / (2 * omega)) if np.isfinite(omega) else float("nan")
    i1, i0 = fit.names.index("a1"), fit.names.index("a0")
    s1, s0 = fit.std[i1], fit.std[i0]
    std = {"omega": float(s0 / (2 * omega)) if np.isfinite(omega) else float("nan"),
           "zeta": float(np.hypot(s1 / (2 * omega), a1 * s0 / (4 * omega ** 3)))
           if np.isfinite(omega) else float("nan"),
           "tau_e": float(fit.std[fit.names.index("tau")]) if "tau" in fit.names else float("nan")}
    level, reasons = mil1797_short_period_level(zeta if not undetermined(zeta, std["zeta"]) else float("nan"),
                                                _graded_delay(fit), category,
                                                omega if not undetermined(omega, std["omega"]) else float("nan"), n_alpha)
    return ShortPeriod(omega, zeta, fit.tau, std, level, reasons, fit, n_alpha)


def _pm(value: float, std: float, unit: str = "", at_bound: bool = False) -> str:
    """``value ± std unit``, or "not determined (why)" (:func:`undetermined`)."""
    why = undetermined(value, std, at_bound)
    return f"not determined ({why})" if why else f"{value:.4g} ± {std:.2g}" + (f" {unit}" if unit else "")


def _graded_delay(fit: TransferFunctionFit) -> float:
    """The equivalent delay a level is graded on: the estimate; at its lower bound 0, its upper
    limit (2 sigma), the delay's criteria being upper limits; NaN where not determined."""
    if "tau" not in fit.names:
        return float("nan")
    std = float(fit.std[fit.names.index("tau")])
    if "tau" in fit.at_bound and abs(fit.tau) < 1e-9:
        return 2 * std if np.isfinite(std) else float("nan")
    return float("nan") if undetermined(fit.tau, std, "tau" in fit.at_bound) else float(fit.tau)


def mil1797_short_period_level(zeta: float, tau_e: float, category: str = "A", omega: float = float("nan"),
                               n_alpha: float | None = None) -> tuple[int | None, list[str]]:
    """MIL-STD-1797A level of the short period: the worst of its damping ratio, equivalent delay and,
    with ``n_alpha`` (g/rad), CAP = omega^2 / (n/alpha) and (category A) the omega minimum; each
    criterion's level in the reasons. None when a graded figure is not determined."""
    if category not in MIL1797_ZETA:
        raise ValueError(f"flight-phase category must be one of {', '.join(MIL1797_ZETA)}, got '{category}'")
    if n_alpha is not None and not (np.isfinite(n_alpha) and n_alpha > 0):
        raise ValueError(f"n/alpha must be a positive number of g/rad, got {n_alpha}")
    if not (np.isfinite(zeta) and np.isfinite(tau_e)) or (n_alpha is not None and not np.isfinite(omega)):
        return None, ["zeta, tau_e" + (" or omega" if n_alpha is not None else "") + " not determined"]
    lz = _level_in(zeta, MIL1797_ZETA[category], 4)
    levels = [lz, next((k for k, t in enumerate(MIL1797_TAU, start=1) if tau_e <= t), 4)]
    reasons = [f"zeta_sp {zeta:.3g}: {_name(lz)} (category {category}){_disputed(zeta, category)}",
               f"tau_e {tau_e:.3g} s: {_name(levels[1])}"]
    if n_alpha is None:
        reasons.append("omega_sp not graded (needs n/alpha)")
    else:
        c = omega ** 2 / n_alpha
        levels.append(_level_in(c, MIL1797_CAP[category], 3))
        reasons.append(f"CAP {c:.3g} 1/(g s^2) (omega_sp {omega:.3g} rad/s, n/alpha {n_alpha:g} g/rad): "
                       f"{_name(levels[-1])}" + (" (outside Level 2)" if levels[-1] == 3 else ""))
        if category in MIL1797_OMEGA_MIN:
            levels.append(next((k for k, w in enumerate(MIL1797_OMEGA_MIN[category], start=1) if omega >= w), 3))
            reasons.append(f"omega_sp {omega:.3g} rad/s: {_name(levels[-1])} (minimum "
                           f"{' / '.join(f'{w:g}' for w in MIL1797_OMEGA_MIN[category])} rad/s)")
        else:
            reasons.append(f"no omega_sp minimum graded for category {category} (none in the sources)")
    return min(max(levels), 3), reasons


def _level_in(x: float, ranges, worse: int) -> int:
    """The first Level whose (min, max) range holds ``x``; ``worse`` if none."""
    return next((k for k, (a, b) in enumerate(ranges, start=1) if a <= x <= b), worse)


def _name(level: int) -> str:
    return f"Level {level}" if level < 4 else "worse than Level 3"


def _disputed(zeta: float, category: str) -> str:
    """Why a damping level is unsure: the (category, Level) limit the sources disagree on, when zeta
    lies between their two values."""
    for (cat, lvl), (low, kept, why) in MIL1797_UNVERIFIED.items():
        if cat == category and min(low, kept) <= zeta < max(low, kept):
            return (f"; UNVERIFIED: Level {lvl} or worse, the Level {lvl} damping minimum is {kept:g} here "
                    f"but {why}")
    return ""


def plot_fit(omega: np.ndarray, H: np.ndarray, coherence: np.ndarray | None, fit: TransferFunctionFit,
             title: str, min_coherence: float = MIN_COHERENCE):
    """Bode plot (magnitude dB, phase deg, coherence against frequency in rad/s, log axis) of the
    measured response beside the fitted transfer function; an Agg :class:`Figure`."""
    from matplotlib.figure import Figure

    coh = np.ones(omega.shape) if coherence is None else coherence
    ok = np.isfinite(H) & (coh >= min_coherence)
    fig = Figure(figsize=(6.0, 6.5))
    a_m, a_p, a_c = fig.subplots(3, 1, sharex=True)
    Hf = fit.response(omega)
    ph_d = np.full(omega.shape, np.nan)
    if ok.any():
        ph_d[ok] = np.degrees(np.unwrap(np.angle(H[ok])))
    ph_f = np.degrees(np.unwrap(np.angle(Hf)))
    if ok.any():  # the fit's phase by whole turns near the data's
        ph_f += 360 * np.round(np.nanmedian(ph_d[ok] - ph_f[ok]) / 360)
    a_m.semilogx(omega[ok], 20 * np.log10(np.abs(H[ok])), "k.", ms=4, label=f"data (coherence >= {min_coherence})")
    a_m.semilogx(omega, 20 * np.log10(np.abs(Hf)), "C3-", lw=1.2, label=f"fit (J {fit.J:.1f})")
    a_p.semilogx(omega[ok], ph_d[ok], "k.", ms=4)
    a_p.semilogx(omega, ph_f, "C3-", lw=1.2)
    a_c.semilogx(omega, coh, "k-", lw=1.0)
    a_c.axhline(min_coherence, color="0.6", ls=":")
    a_c.set_ylim(0, 1.05)
    a_m.set_ylabel("magnitude [dB]")
    a_p.set_ylabel("phase [deg]")
    a_c.set_ylabel("coherence [-]")
    a_c.set_xlabel("frequency [rad/s]")
    a_m.legend(fontsize=7)
    a_m.set_title(title, fontsize=9)
    fig.tight_layout()
    return fig
