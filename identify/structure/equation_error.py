"""The fast pass: stepwise regression of the state equations in equation error.

Each dynamic equation (or group of equations a tied parameter joins) is one
:class:`~identify.structure.regression.Problem`: the dependent variable is the state derivative
(a ``<state>_dot`` channel, an output that holds it, or smoothed differentiation of the measured
state: :func:`identify.estimators.equation_error.state_derivatives`) minus the profile's known
part (gravity, kinematics), the columns are the regressors of the profile's free parameters and of
the pool's candidates (:mod:`identify.structure.pool`), with a zero shift per run and equation.
Parameters that act only on the output equation (scale factors) are outside equation error and
left as they are.
"""
from __future__ import annotations

import numpy as np

from ..data.runs import Run
from ..errors import EstimationError
from ..estimators.equation_error import equation_groups, fixed_part, regressors, state_derivatives
from ..model.linear import LinearModel
from ..model.profile import Profile
from .regression import Problem, Selection, Stepwise


def problems(ext: Profile, declared: Profile, runs: list[Run], diff_cutoff_hz: float | None = None) -> list[Problem]:
    """The regression problems of the extended profile ``ext`` on ``runs`` (pseudo-inputs present)."""
    for run in runs:
        run.require(ext.state_names, "structure determination in equation error (every state must be measured)")
    model = LinearModel(ext)
    data = []
    for run in runs:
        x, u = run.matrix(ext.state_names), run.matrix(ext.input_names)
        xdot, _ = state_derivatives(run, ext, diff_cutoff_hz)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(u)) and np.all(np.isfinite(xdot))):
            raise EstimationError(f"{run.source}: non-finite state, input or derivative: equation error needs "
                                  f"complete data (read the runs with --nan drop or interpolate)")
        data.append((xdot - fixed_part(model, x, u), regressors(model, x, u)))
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


def select(ext: Profile, declared: Profile, runs: list[Run], stepwise: Stepwise,
           diff_cutoff_hz: float | None = None) -> list[Selection]:
    """Stepwise regression of every problem."""
    return [stepwise.select(pr) for pr in problems(ext, declared, runs, diff_cutoff_hz)]


__all__ = ["problems", "select"]
