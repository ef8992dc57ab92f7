"""Filter-error method (FEM): maximum likelihood with process noise (Maine & Iliff; Jategaonkar ch. 5).

Output error (:mod:`identify.estimators.ml`) takes every misfit for measurement noise; flight data
are flown in turbulence, whose response output error cannot tell from a wrong derivative. The
filter-error method models both noises::

    dx/dt = A x + B u + F w          w: unit white noise (power spectral density 1)
    y     = C x + D u + b + v        v: white measurement noise, covariance R (diagonal)

F is diagonal on the states with process noise (``[process_noise]`` of the profile; default the
velocity equations u, v, w), F_i in the state-derivative unit times sqrt(s) (a white gust forcing
of F_i^2 per rad/s of bandwidth). Discretised exactly (matrix exponentials: ``Phi``, ``Gamma`` for
the inputs held or linear between samples; ``Qd = int_0^dt e^{A s} F F^T e^{A^T s} ds`` by Van
Loan), the steady-state Kalman filter in predictor form propagates the state::

    P  = solve_discrete_are(Phi^T, C^T, Qd, R)     (a priori state error covariance)
    S  = C P C^T + R                               (innovation covariance)
    Kp = Phi P C^T S^-1                            (predictor gain; K = P C^T S^-1 the filter's)
    x[k+1] = Phi x[k] + Gamma u[k] + Kp nu[k],     nu[k] = z[k] - C x[k] - D u[k] - b

and the cost is the negative log-likelihood of the innovations over all runs (constant dropped),
``J = 1/2 sum nu^T S^-1 nu + N/2 log det S``. The filter is a stable system driven by the inputs
and the measurements, so an unstable aircraft needs no multiple shooting: the filter stabilises
the prediction.

Unknowns: the derivatives theta, F, each run's initial state (those the profile's
``[initial_state]`` or the ``x0`` option do not fix) and each run's zero shifts (per output, as
the profile's ``[zero_shifts]`` says). They move by Levenberg-Marquardt steps on the Fisher
information (Gauss-Newton on the innovations, plus the information of S, which moves with theta
and F: ``M_ij = sum dnu_i^T S^-1 dnu_j + N/2 tr(S^-1 dS_i S^-1 dS_j)``); trust region and
convergence test are the one solver's (:mod:`identify.estimators.lm`: step under 1e-3 standard errors).

R starts by *relaxation* from the first innovations, with the process noise's share removed
("F compensation"): ``R_jj = mean(nu_j^2) - (C P C^T)_jj`` (floored at a tiny positive share of
mean(nu_j^2)); from then on its variances are unknowns of the same scoring steps (relaxation
alone stalled on a wrong fixed point in the tests: with R held, the likelihood's dependence on
it through the gain is lost). Where that start falls below the floor, R starts from the innovation
covariance with the gain held; the likelihood can then have two optima, and FEM also fits from the
process noise's side (F from the states' whole rms, R on its floor), then once more from the better
fit's derivatives with the noise started afresh from that side, keeping the higher likelihood
(:mod:`.starts`, ``info["r_start"]``). R >= 0 keeps the filter physically admissible:
``C K = I - R S^-1`` has ``diag(C K) = 1 - R_jj (S^-1)_jj <= 1`` (reported as ``info["diag_CK"]``).
An F that falls to ~0 (calm air on that state) or a variance pushed onto its floor is held
there: a boundary estimate, its bound "not determined" (NaN, listed in ``info["not_determined"]``).

Sensitivities: the filter is linear in its state, ``x[k+1] = Abar x[k] + (Gamma - Kp D) u[k] +
Kp (z[k] - b)`` with ``Abar = Phi - Kp C``, so the derivatives of the innovations with respect
to all unknowns come from one recursion with Abar, all parameters and runs propagated together as
trailing columns (as the output-error engine does): ``dx[k+1] = Abar dx[k] + dAbar x[k] + ...``.
``dPhi`` and ``dGamma`` are exact (Van Loan, :func:`~identify.model.sensitivity.discretize_with_derivatives`);
the gain's and S's derivatives come from the derivative of the Riccati solution, one discrete
Lyapunov equation for all unknowns at once (:meth:`FilterProblem._gain_derivatives`), with only
Qd's derivatives by central differences of a batched matrix exponential: no re-filtering and no
extra Riccati solve.

Bounds: the Cramér-Rao bounds from the same information at the estimate, the measurement-noise
variances included as unknowns (their sensitivities through the gain as above), so
F and R are reported with their bounds. For F = 0 (no process noise) and a stable model the
filter's gain is zero and FEM is output-error ML (plain form).

Outputs that are state derivatives (p_dot, a_y) use the model's noise-free derivative
``C x + D u`` (the convention of Maine & Iliff and Jategaonkar: continuous white noise has no
finite sample value; its effect on such outputs is absorbed by R).

Profiles with state-built nonlinear terms (q|q|): the extended Kalman filter of
:mod:`.nonlinear` (:class:`NonlinearFilterProblem`), the rest as above.

The family (one concern a module): :mod:`.base` (conventions; the process-noise model, the seam
where a turbulence model plugs in), :mod:`.filter` (the Kalman filter, its sensitivities and
information), :mod:`.nonlinear` (the extended filter), :mod:`.solver` (the fit on the one
Levenberg-Marquardt solver), :mod:`.starts` (the noise's starts and the restart), :mod:`.bounds`
(Cramér-Rao and coloured bounds), :mod:`.estimator` (:class:`FEM`).
"""
from __future__ import annotations

from .base import F_START, F_ZERO, PROCESS_NOISE_CONVENTION, R_FLOOR, ProcessNoiseModel
from .estimator import FEM
from .filter import Filtered, FilterProblem, NonlinearFilterProblem
from .solver import FilterSolver

__all__ = ["FEM", "FilterProblem", "Filtered", "FilterSolver", "NonlinearFilterProblem", "ProcessNoiseModel",
           "PROCESS_NOISE_CONVENTION", "R_FLOOR", "F_START", "F_ZERO"]
