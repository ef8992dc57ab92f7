"""The fast pass: stepwise regression of the state equations in equation error.

Each dynamic equation (or group of equations a tied parameter joins) is one
:class:`~identify.structure.regression.Problem`: the dependent variable is the state derivative
(a ``<state>_dot`` channel, an output that holds it, or smoothed differentiation of the measured
state: :func:`identify.estimators.equation_error.state_derivatives`) minus the profile's known
part (gravity, kinematics), the columns are the regressors of the profile's free parameters and of
the pool's candidates (:mod:`identify.structure.pool`), with a zero shift per run and equation.
Parameters that act only on the output equation (scale factors) are outside equation error and
left as they are.

A coefficient-form profile (:mod:`identify.model.coefficients`) is regressed in its coefficients:
the dependent variable of an equation in ``meta.coefficients.equations`` is its coefficient
(``C_m = I q_dot / (qbar S c)`` sample by sample, forces from the accelerometers), a coefficient
derivative's column its non-dimensional variable (alpha, q c / 2V, the input) and a dimensional
parameter's column its regressor in the same units (divided by ``qbar S / m`` or ``qbar S c / I``).
"""
from __future__ import annotations

import numpy as np

from ..data.runs import Run
from ..errors import EstimationError
from ..estimators.equation_error import equation_groups, fixed_part, regressors, state_derivatives
from ..model import coefficients as cf
from ..model.linear import LinearModel
from ..model.profile import Profile
from .regression import Problem, Selection, Stepwise


def problems(ext: Profile, declared: Profile, runs: list[Run], diff_cutoff_hz: float | None = None) -> list[Problem]:
    """The regression problems of the extended profile ``ext`` on ``runs`` (pseudo-inputs present)."""
    for run in runs:
        run.require(ext.state_names, "structure determination in equation error (every state must be measured)")
    model = LinearModel(ext)
    table = cf.spec(ext.meta, ext.source)
    data = []
    for run in runs:
        x, u = run.matrix(ext.state_names), run.matrix(ext.input_names)
        xdot, _ = state_derivatives(run, ext, diff_cutoff_hz)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(u)) and np.all(np.isfinite(xdot))):
            raise EstimationError(f"{run.source}: non-finite state, input or derivative: equation error needs "
                                  f"complete data (read the runs with --nan drop or interpolate)")
        y, reg = xdot - fixed_part(model, x, u), regressors(model, x, u)
        if table is not None:
            y, reg = _in_coefficients(ext, model, table, run, y, reg)
        data.append((y, reg))
    out = []
    for g in equation_groups(model):
        label = "+".join(ext.equation(ext.state_names[e]) for e in g.equations)
        ys, cols, blocks, start = [], {model.names[j]: [] for j in g.params}, [], 0
        for y, reg in data:
            for e in g.equations:
                ys.append(y[:, e])
                for j in g.params:
                    cols[model.names[j]].append(reg[:, e, j])
                blocks.append((start, start + len(y)))
                start += len(y)
        out.append(Problem(label, np.concatenate(ys), {k: np.concatenate(v) for k, v in cols.items()}, blocks,
                           declared=tuple(k for k in cols if k in declared.free)))
    return out


def _in_coefficients(p: Profile, model: LinearModel, table: dict, run: Run, y: np.ndarray, reg: np.ndarray):
    """The coefficient equations' dependent variables and columns in coefficient units."""
    y, reg = y.copy(), reg.copy()
    equations = dict(table["equations"])
    rows = {p.equation(s): i for i, s in enumerate(p.state_names)}
    aero = {eq: y[:, i].copy() for eq, i in rows.items()}
    for eq, coef in equations.items():
        if eq not in rows:
            raise EstimationError(f"{p.source}: meta.coefficients: no state equation {eq}")
        i = rows[eq]
        measured = cf.measured(run, eq, table, aero[eq], aero)
        scale = cf.dynamic_pressure(run, table) * float(table["area"])
        # a dimensional parameter's column in the coefficient's units (lift and drag: against Z and X)
        unit = cf.COEFFICIENTS[coef][1] * (float(table["mass"]) if eq not in cf.MOMENTS else
                float(dict(table["inertia"])[eq]) / float(table[cf.MOMENTS[eq]])) / scale
        y[:, i] = measured
        for j, name in enumerate(model.names):
            parts = cf.split_name(name, table)
            if parts is not None and parts[0] == coef:
                reg[:, i, j] = cf.regressor(run, parts[1], table, p.state_names)
            else:
                reg[:, i, j] = unit * reg[:, i, j]
    return y, reg


def held_out_error(fit_problem: Problem, held_out: Problem, terms: list[str]) -> float:
    """RMS error of the least-squares model on ``terms`` (fitted on ``fit_problem``) predicting
    ``held_out``, each block's zero shift re-fitted, divided by the held-out data's RMS about
    those: 0 a perfect prediction, 1 none better than the zero shifts."""
    y, cols = fit_problem.demeaned()
    yv, colsv = held_out.demeaned()
    X = np.column_stack([cols[t] for t in terms]) if terms else np.zeros((len(y), 0))
    theta = np.linalg.lstsq(X, y, rcond=None)[0] if terms else np.zeros(0)
    Xv = np.column_stack([colsv[t] for t in terms]) if terms else np.zeros((len(yv), 0))
    e = yv - Xv @ theta
    return float(np.sqrt(np.mean(e ** 2) / max(np.mean(yv ** 2), 1e-300)))


def select(ext: Profile, declared: Profile, runs: list[Run], stepwise: Stepwise,
           diff_cutoff_hz: float | None = None) -> list[Selection]:
    """Stepwise regression of every problem."""
    return [stepwise.select(pr) for pr in problems(ext, declared, runs, diff_cutoff_hz)]


__all__ = ["problems", "select", "held_out_error"]
