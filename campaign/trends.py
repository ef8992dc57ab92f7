"""Each derivative against the flight condition: a smooth trend, the points that break it.

The trend of a parameter is a polynomial in the (scaled) condition fitted by weighted least
squares (weights 1/std^2 of each point's estimate), its degree (0 to 3) the one with the lowest
BIC; its covariance is inflated by the reduced chi-square when the points scatter more than their
standard errors say (never deflated). A point *breaks the trend* when it lies more than 3 standard
deviations (its own and the trend's at that condition, combined) from the trend fitted without it
(leave one out, so that the point cannot pull the trend towards itself); those points are left
out of the final trend. A point's own std is taken at the campaign's observed scatter when that
is larger (:func:`scatter_ratio`, robust): Cramér-Rao bounds from turbulent flight data are
optimistic, and at their face value about one point in 20 would "break" some trend by chance. A point is *poorly identified* when its relative standard error exceeds
the Cramér-Rao guideline (20 %, Tischler & Remple) or its fit did not converge; it is shaded in
the plots and weighs little in the trend (its large std).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

BREAK_SIGMA = 3.0
POOR_REL_STD = 20.0  # %: the Cramér-Rao guideline (identify.estimators.result.CR_GUIDELINE)
MAX_DEGREE = 3


@dataclass
class Fit:
    """A weighted polynomial in ``(x - centre) / scale``: ``coef`` (d+1,), ``cov`` (d+1, d+1)."""

    coef: np.ndarray
    cov: np.ndarray
    centre: float
    scale: float
    chi2_dof: float

    def __call__(self, x) -> tuple[np.ndarray, np.ndarray]:
        """Value and standard deviation of the trend at ``x``."""
        V = self._vander(np.atleast_1d(np.asarray(x, float)))
        return V @ self.coef, np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", V, self.cov, V), 0.0))

    def _vander(self, x):
        return np.vander((x - self.centre) / self.scale, len(self.coef), increasing=True)

    @property
    def degree(self) -> int:
        return len(self.coef) - 1


def polyfit(x, y, std, degree: int) -> Fit:
    """Weighted LS polynomial of ``degree``; ``std`` None or 0 everywhere: unweighted, the
    covariance from the residual scatter."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    centre, scale = float(np.mean(x)), float(np.ptp(x) / 2 or 1.0)
    weighted = std is not None and np.all(np.asarray(std) > 0)
    w = 1 / np.asarray(std, float) if weighted else np.ones_like(y)
    V = np.vander((x - centre) / scale, degree + 1, increasing=True)
    coef, *_ = np.linalg.lstsq(V * w[:, None], y * w, rcond=None)
    r = (y - V @ coef) * w
    dof = len(y) - degree - 1
    chi2_dof = float(r @ r / dof) if dof > 0 else math.nan
    cov = np.linalg.pinv((V * w[:, None]).T @ (V * w[:, None]))
    cov *= max(chi2_dof, 1.0) if weighted and dof > 0 else (chi2_dof if dof > 0 else math.inf)
    return Fit(coef, cov, centre, scale, chi2_dof)


def best_fit(x, y, std, max_degree: int = MAX_DEGREE) -> Fit:
    """The polynomial of degree 0..max_degree with the lowest BIC (the weighted chi-square plus
    the number of coefficients times log n); at least 2 more points than coefficients."""
    n = len(x)
    best, best_bic = None, math.inf
    for d in range(0, min(max_degree, n - 2) + 1):
        f = polyfit(x, y, std, d)
        chi2 = f.chi2_dof * (n - d - 1)
        weighted = std is not None and np.all(np.asarray(std) > 0)
        bic = (chi2 if weighted else n * math.log(max(chi2 / n, 1e-300))) + (d + 1) * math.log(n)
        if bic < best_bic:
            best, best_bic = f, bic
    if best is None:  # fewer than 2 points: a constant
        best = polyfit(x, y, std, 0)
    return best


@dataclass
class Trend:
    """One parameter over the condition: per point ``x``, ``value``, ``std``, ``breaks`` (more than
    3 std off the leave-one-out trend), ``poor``; ``fit`` the trend from the points kept."""

    parameter: str
    points: list[str]
    x: np.ndarray
    value: np.ndarray
    std: np.ndarray
    poor: np.ndarray
    breaks: np.ndarray = field(default=None)
    z: np.ndarray = field(default=None)
    fit: Fit | None = None
    scale: float = 1.0  # the points' scatter about the trend in units of their std (>= 1)


def trend(parameter: str, points, x, value, std, poor) -> Trend:
    """Fit the trend, flag the points that break it (see the module docstring)."""
    x, value, std, poor = (np.asarray(a, float) for a in (x, value, std, poor))
    poor = poor.astype(bool)
    usable = np.isfinite(value) & np.isfinite(std) & (std > 0)
    resid, sd = np.full(len(x), np.nan), np.full(len(x), np.nan)
    idx = np.flatnonzero(usable)
    if len(idx) >= 4:  # fewer leave no trend to break
        for i in idx:
            rest = idx[idx != i]
            mean, s = best_fit(x[rest], value[rest], std[rest])(x[i])
            resid[i], sd[i] = value[i] - mean[0], s[0]
    scale = scatter_ratio(resid[idx] / std[idx]) if len(idx) >= 4 else 1.0
    z = resid / np.hypot(scale * std, sd)
    breaks = np.abs(z) > BREAK_SIGMA
    kept = usable & ~breaks
    fit = best_fit(x[kept], value[kept], std[kept]) if kept.sum() >= 1 else None
    return Trend(parameter, list(points), x, value, std, poor, breaks, z, fit, scale)


def scatter_ratio(normalised: np.ndarray) -> float:
    """How much more the points scatter about their trend than their standard errors say: the
    robust standard deviation (1.4826 x median absolute deviation) of the residuals in units of
    each point's std, never below 1. Robust, so that the points with an undeclared effect (a few
    at tens of std) do not hide themselves by inflating it."""
    r = normalised[np.isfinite(normalised)]
    if r.size < 4:
        return 1.0
    return max(1.0, float(1.4826 * np.median(np.abs(r - np.median(r)))))


def campaign_trends(table: list[dict], condition: str) -> list[Trend]:
    """A :class:`Trend` per parameter from the tidy table's rows (points with estimates only;
    points that did not converge are kept, shaded, but out of the trend)."""
    by_param: dict[str, list[dict]] = {}
    for row in table:
        if row.get("parameter") and isinstance(row.get(condition), (int, float)):
            by_param.setdefault(row["parameter"], []).append(row)
    out = []
    for name, rows in by_param.items():
        rows = sorted(rows, key=lambda r: r[condition])
        conv = np.array([r["converged"] is True for r in rows])
        std = np.array([r["std"] if r["converged"] is True else math.inf for r in rows], float)
        poor = ~conv | ~(np.array([r["rel_std_pct"] for r in rows], float) <= POOR_REL_STD)
        out.append(trend(name, [r["point"] for r in rows], [r[condition] for r in rows],
                         [r["value"] for r in rows], std, poor))
    return out


def plot_trends(trends: list[Trend], condition: str, path, title: str = "") -> None:
    """One panel per parameter: estimates with 1-std error bars against the condition, the
    trend with its 2-std band, points breaking it circled red, poorly identified ones shaded."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    n = len(trends)
    cols = min(3, n) or 1
    rows = math.ceil(n / cols) or 1
    fig = Figure(figsize=(4.2 * cols, 2.9 * rows), layout="constrained")
    FigureCanvasAgg(fig)
    for k, t in enumerate(trends):
        ax = fig.add_subplot(rows, cols, k + 1)
        span = np.ptp(t.x) or 1.0
        for xi in t.x[t.poor]:
            ax.axvspan(xi - 0.006 * span, xi + 0.006 * span, color="0.85", zorder=0, lw=0)
        good = ~t.poor
        finite_std = np.where(np.isfinite(t.std), t.std, 0.0)
        ax.errorbar(t.x[good], t.value[good], yerr=finite_std[good], fmt="o", ms=3, lw=0.8, color="C0",
                    label="estimate ± 1 std")
        ax.errorbar(t.x[t.poor], t.value[t.poor], yerr=finite_std[t.poor], fmt="o", ms=3, lw=0.8,
                    color="0.55", label="poorly identified (shaded)")
        if t.fit is not None:
            grid = np.linspace(t.x.min(), t.x.max(), 200)
            mean, sd = t.fit(grid)
            ax.plot(grid, mean, color="C1", lw=1.2, label=f"trend (degree {t.fit.degree})")
            ax.fill_between(grid, mean - 2 * sd, mean + 2 * sd, color="C1", alpha=0.25, lw=0)
        if t.breaks.any():
            ax.plot(t.x[t.breaks], t.value[t.breaks], "o", ms=10, mfc="none", mec="red", mew=1.5,
                    label=f"breaks trend (> {BREAK_SIGMA:g} std)")
        ax.set_title(t.parameter, fontsize=10)
        ax.set_xlabel(condition, fontsize=8)
        ax.tick_params(labelsize=7)
        if k == 0:
            ax.legend(fontsize=6)
    if title:
        fig.suptitle(title, fontsize=11)
    fig.savefig(path, dpi=110)
