"""Score tests of every candidate at the fitted model: :func:`score_candidates` gives
:class:`ScoreTest` records (statsmodels' shape: a nested-model test as a result object).

Two noise models, two families of tests, Šidák-corrected together: the *residual* model (lines and
trends removed) tests every candidate, but learns an effect that dominates the residual as colour
(a 0.1 s delay: score 5477 white, 4 in its metric); so the ``TOP_ALTERNATIVE`` candidates that
explain most of the residual's energy, and the ``TOP_ALTERNATIVE`` scoring highest in its metric,
are tested again in an *alternative* model fitted with that candidate's own least-squares fit
removed (all candidates' columns removed at once biased it:
smooth terms scored 75 for a threshold of 22), and nothing else (each run's mean, trend and line,
removed before the residual model is fitted, took further low-frequency noise out of it).

A noise model fitted without the candidate's own fit estimates the noise level along the
candidate's columns from ``nu`` dof less the ``q`` that fit took: the statistic is then F-like,
``S (nu - q) / (q nu)`` ~ F(q, nu - q), ``nu`` the Satterthwaite dof of that level
(:meth:`NoiseModel.effective_dof`), few for a smooth column (a derivative, a drift: 13-30 on a
30 s Navion run), hundreds for a broadband one (a delay). So are drift and bias in the residual
model's metric: each run's trend and mean are removed before it is fitted.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy import stats

from ..model.profile import Profile
from . import diagnostics as dg
from .candidates import Candidate, Context, catalogue, extend_all
from .evaluation import unexplaining
from .fitting import Fitting
from .noise import NoiseModel

SIMPLER_FIRST = math.log(100.0)  # a nonlinear term ranks as if its p-value were 100 times larger
TOP_ALTERNATIVE = 3  # candidates also tested in the metric of their own alternative noise model


@dataclass(eq=False)
class ScoreTest:
    """One candidate's score test: chi-square ``statistic`` with ``dof`` degrees of freedom in the
    metric of ``noise`` (``metric``: of the ``residual`` or of the candidate's ``alternative``);
    ``threshold`` at the Šidák ``level`` over ``n_tests`` hypotheses; ``hint`` a linearised
    estimate (where a non-linear candidate's search starts)."""

    candidate: Candidate
    statistic: float
    dof: int
    log_p: float
    noise: NoiseModel
    metric: str
    hint: np.ndarray | None = None
    nu: float = math.inf  # dof of the noise variance along the candidate (finite: F, not chi-square)
    n_tests: int = 1
    level: float = math.nan
    threshold: float = math.nan

    @property
    def p_value(self) -> float:
        return float(math.exp(self.log_p))

    @property
    def significant(self) -> bool:
        return self.statistic > self.threshold

    def rank(self) -> tuple:
        """Order of preference among significant candidates: smallest p-value first, a nonlinear
        term (more complex than a derivative, delay, bias, drift, scale or vibration) as if its
        p-value were 100 times larger."""
        return (self.log_p + SIMPLER_FIRST * self.candidate.complexity, -self.statistic)

    def to_dict(self) -> dict:
        return {"effect": self.candidate.kind, "target": self.candidate.target, "statistic": self.statistic,
                "threshold": self.threshold, "dof": self.dof, "metric": self.metric,
                "nu": self.nu if math.isfinite(self.nu) else None}


@dataclass
class ScoreRound:
    """The tests of one round and the residual noise model they used."""

    tests: list[ScoreTest]
    noise: NoiseModel
    n_candidates: int


def score_candidates(fitting: Fitting, p: Profile, kinds, excluded: set[str], *, alpha: float,
                     coloured: bool = True, f_min: float = 0.5, frequencies=(), products: bool = True) -> ScoreRound:
    """Score statistic, threshold and p-value of every candidate of ``kinds`` (not ``excluded``)
    at the fitted profile ``p`` (see the module notes; ``f_min``, ``frequencies`` (Hz) and
    ``products`` as :class:`~identify.refine.candidates.Context` takes them).

    Each candidate's test depends only on the fitted model and its own columns, not on which
    others are tested: the tests at ``p`` are kept (:class:`_Tests`, in ``fitting.cache``), and a
    round at the same model after a rejection (one more candidate ``excluded``) computes only the
    alternative metrics it newly selects; the Šidák correction is over the round's own family."""
    state = _Tests.at(fitting, p, kinds, excluded, coloured, f_min, tuple(frequencies), products)
    groups = [g for g in state.groups if g[0].name not in excluded]
    tested = [state.residual[c.name] for c, _ in groups if state.residual[c.name] is not None]
    if coloured:
        residual_log_p = {t.candidate.name: t.log_p for t in tested}
        energy = np.array([state.energy[c.name] for c, _ in groups])
        tested += state.alternatives([groups[i] for i in _explaining_most(energy, groups, residual_log_p)])
    # Šidák over every elementary hypothesis of both families (a periodic candidate: n_tests bins)
    n_tests = sum(t.candidate.n_tests for t in tested)
    level = 1.0 - (1.0 - alpha) ** (1.0 / max(n_tests, 1))
    best: dict[str, ScoreTest] = {}
    for t in tested:
        t = replace(t, n_tests=n_tests, level=level, threshold=_threshold(level, t.dof, t.nu))
        name = t.candidate.name
        if name not in best or t.log_p < best[name].log_p:
            best[name] = t
    return ScoreRound(list(best.values()), state.null, sum(c.name not in excluded for c in state.cands))


class _Tests:
    """The score tests of the candidates at one fitted profile: their columns, the residual noise
    model, each one's test in its metric (``residual``: name -> test, None where the candidate is
    not testable) and white ``energy``, and the tests in alternative metrics computed so far;
    ``excluded`` the candidates left out when they were computed."""

    def __init__(self, fitting: Fitting, p: Profile, kinds, excluded: set[str], coloured: bool, f_min: float,
                 frequencies: tuple, products: bool):
        self.fitting, self.f_min = fitting, f_min
        ev = fitting.prediction(p)
        context = Context(ev.runs, ev.residuals, fitting.dt, f_min, frequencies, products, held=fitting.held)
        self.excluded = set(excluded)
        self.cands = cands = [c for c in catalogue(p, context, kinds) if c.name not in excluded]
        ext_p, linear = extend_all(p, [c for c in cands if c.linear])
        ext_runs = ev.runs
        for c in linear:
            ext_runs = c.runs(ext_runs)
        evj = fitting.sensitivities(ext_p, ext_runs, ev)
        # per run (N_r, ny, columns): the model's parameters, then every candidate's columns
        own = [(c, c.score_columns(fitting, p)) for c in cands if not c.linear]
        dy = [np.concatenate([d] + [cols[r] for _, cols in own], axis=2) for r, d in enumerate(evj.dy)]
        nb = len(p.free)
        col = {name: i - nb for i, name in enumerate(ext_p.free_names)}
        self.groups = [(c, [col[k] for k in c.params]) for c in linear]
        width = len(ext_p.free) - nb
        for c, cols in own:
            self.groups.append((c, list(range(width, width + cols[0].shape[2]))))
            width += cols[0].shape[2]
        sigma = np.sqrt(np.mean(np.vstack(ev.residuals) ** 2, axis=0))
        self.sigma = np.where(sigma > 0, sigma, 1.0)
        self.design = (ev.residuals, dy, evj.nuisance, nb)
        self.null = NoiseModel.fit(ev.residuals, fitting.dt, f_min, segment=fitting.segment) if coloured \
            else NoiseModel.white(self.sigma)
        tests = {t.candidate.name: t for t in _tests(self.null, self.design, self.groups, "residual")}
        self.residual = {c.name: tests.get(c.name) for c, _ in self.groups}
        self.energy = dict(zip([c.name for c, _ in self.groups], dg.residual_energy(
            ev.residuals, [d[:, :, nb:] for d in dy], [g for _, g in self.groups], self.sigma))) if coloured else {}
        self.alternative: dict[str, list[ScoreTest]] = {}
        self.unexplained = None  # the residual's least-squares fit with a candidate's columns added (once built)

    @classmethod
    def at(cls, fitting: Fitting, p: Profile, kinds, excluded: set[str], *options) -> "_Tests":
        """The tests at ``p`` kept from an earlier round that excluded no more candidates (the
        loop re-scores the same model after a rejection, one more excluded), else computed; only
        the latest profile's are kept (they hold every candidate's columns)."""
        key = ("score tests", p.to_toml(), tuple(kinds), *options)
        state = fitting.cache.get(key)
        if state is None or not state.excluded <= set(excluded):
            fitting.forget("score tests")
            state = fitting.cache[key] = cls(fitting, p, kinds, excluded, *options)
        return state

    def alternatives(self, chosen: list[tuple]) -> list[ScoreTest]:
        """The tests of the ``chosen`` groups each in the metric of its own alternative noise model
        (fitted to the residual with the candidate's least-squares fit removed), computed once."""
        new = [g for g in chosen if g[0].name not in self.alternative]
        if new:
            residuals, dy, nuisance, nb = self.design
            if self.unexplained is None:
                self.unexplained = unexplaining(residuals, [d[:, :, :nb] for d in dy], nuisance, self.sigma)
            each = self.unexplained([[d[:, :, [nb + k for k in cols]] for d in dy] for _, cols in new])
            for (c, cols), clean in zip(new, each):
                alt = NoiseModel.fit(clean, self.fitting.dt, self.f_min, segment=self.fitting.segment,
                                     deterministic=False)
                self.alternative[c.name] = _tests(alt, self.design, [(c, cols)], "alternative")
        return [t for c, _ in chosen for t in self.alternative[c.name]]


def _explaining_most(energy: np.ndarray, groups: list[tuple], residual_log_p: dict) -> list[int]:
    """The groups most likely to be the effect the residual model learnt as colour, ranked as the
    selection ranks significant candidates (by p-value, a nonlinear term as if 100 times less
    likely): the ``TOP_ALTERNATIVE`` whose white ``energy`` (for their number of columns) is the
    largest, and the ``TOP_ALTERNATIVE`` with the largest score in the residual model's metric.

    Raw energy alone failed in two ways on a hovering helicopter in gusts with a pilot in the
    loop (benchmarks/refine_blind.py, two_effects): the many nonlinear products of the full
    catalogue, each correlated with a missing M_v, took every slot (M_v scored 249 in its own
    alternative metric and was never tested there); and once M_v was added, the gust response
    of 3.8 s segments swamped the white energy of a 0.08 s delay's column (not in the top six),
    whose score in the residual metric was the second largest (13.9; 502 in its own metric)."""
    simpler = [SIMPLER_FIRST * c.complexity for c, _ in groups]
    white = [float(stats.chi2.logsf(e, len(cols))) + s for e, (c, cols), s in zip(energy, groups, simpler)]
    metric = [residual_log_p.get(c.name, 0.0) + s for (c, _), s in zip(groups, simpler)]
    chosen = list(np.argsort(white, kind="stable")[:TOP_ALTERNATIVE])
    chosen += [i for i in np.argsort(metric, kind="stable")[:TOP_ALTERNATIVE] if i not in chosen]
    return chosen


def _tests(noise: NoiseModel, design: tuple, groups: list[tuple], metric: str) -> list[ScoreTest]:
    """Score tests of candidate column ``groups`` in the metric of ``noise``; ``design`` =
    (residuals, per-run columns [model | candidates], per-run nuisance columns, model count)."""
    residuals, dy, nuisance, nb = design
    used = sorted({k for _, cols in groups for k in cols})  # whiten only the columns tested
    where = {k: i for i, k in enumerate(used)}
    dyw = [noise.whiten(d[:, :, list(range(nb)) + [nb + k for k in used]]) for d in dy]
    nuisance_w = [noise.whiten(x) for x in nuisance]
    sb = dg.ScoreBase.from_blocks([noise.whiten(e) for e in residuals], [d[:, :, :nb] for d in dyw], nuisance_w)
    J = np.concatenate([d[:, :, nb:].reshape(len(d) * d.shape[1], -1) for d in dyw])
    out = []
    base_q = None  # the model's and nuisance columns whitened, in the coordinates of sb's basis (once)
    for (c, cols), (stat, q) in zip(groups, sb.statistics(J, [[where[k] for k in cols] for _, cols in groups])):
        if q == 0:
            continue  # lies in the span of the model and its nuisance parameters: not testable
        q = max(q, c.null_dof or 0)
        nu = math.inf
        if metric == "alternative" or c.removed_by_noise_fit:
            if base_q is None:
                base_q = _block_product(sb.Q.T, sb.row_runs, [d[:, :, :nb] for d in dyw], nuisance_w)
            nu = _noise_dof(noise, sb, ([d[:, :, :nb] for d in dy], nuisance), base_q,
                            [d[:, :, [nb + k for k in cols]] for d in dy])
        out.append(ScoreTest(c, stat, q, _log_sf(stat, q, nu), noise, metric, nu=nu,
                             hint=None if c.linear else sb.linear_estimate(J[:, [where[cols[0]]]])))
    return out


def _log_sf(stat: float, q: int, nu: float) -> float:
    """log p-value of a score statistic with ``q`` dof in a noise model whose level along the
    candidate rests on ``nu`` dof, ``q`` of them the candidate's own fit removed before it was
    fitted: ``stat (nu - q) / (q nu)`` against F(q, nu - q) (the Wald statistic's exact law in
    linear regression, ``n`` observations, ``k`` parameters: ``q F n / (n - k)``); chi-square for
    ``nu`` infinite."""
    if not math.isfinite(nu):
        return float(stats.chi2.logsf(stat, q))
    d = max(nu - q, 1.0)
    return float(stats.f.logsf(stat * d / (q * (d + q)), q, d))


def _threshold(level: float, q: int, nu: float) -> float:
    """The statistic :func:`_log_sf` gives the p-value ``level``."""
    if not math.isfinite(nu):
        return float(stats.chi2.isf(level, q))
    d = max(nu - q, 1.0)
    return float(q * (d + q) / d * stats.f.isf(level, q, d))


def _noise_dof(noise: NoiseModel, sb: dg.ScoreBase, base: tuple, base_q: np.ndarray,
               columns: list[np.ndarray]) -> float:
    """Degrees of freedom of ``noise``'s level along a candidate's ``columns`` (per run (N_r, ny, q))
    less their fit, in that metric, on the model's and nuisance columns (``base``: per run, the
    shared and the run's own, as :func:`block_design` takes them; ``base_q`` the whitened ones in
    the coordinates of their basis ``sb.Q``): :meth:`NoiseModel.effective_dof`."""
    Jw = np.concatenate([noise.whiten(c).reshape(-1, c.shape[2]) for c in columns])
    coef = np.linalg.lstsq(base_q, sb.Q.T @ Jw, rcond=None)[0]
    shared, per_run = base
    nb, first = shared[0].shape[2], np.cumsum([0] + [x.shape[2] for x in per_run])
    rest = [c - s @ coef[:nb] - x @ coef[nb + a:nb + b]
            for c, s, x, a, b in zip(columns, shared, per_run, first[:-1], first[1:])]
    return noise.effective_dof(rest)


def _block_product(A: np.ndarray, rows: list[slice], shared: list[np.ndarray],
                   per_run: list[np.ndarray]) -> np.ndarray:
    """``A @ block_design(shared, per_run)`` without the design: each run's own columns meet only
    that run's columns of ``A`` (``rows``: each run's rows of the stacked design, as
    :attr:`ScoreBase.row_runs` holds them)."""
    stacked = np.concatenate([s.reshape(-1, s.shape[2]) for s in shared])
    return np.hstack([A @ stacked] + [A[:, r] @ x.reshape(-1, x.shape[2]) for r, x in zip(rows, per_run)])

__all__ = ["ScoreTest", "ScoreRound", "score_candidates", "SIMPLER_FIRST", "TOP_ALTERNATIVE"]
