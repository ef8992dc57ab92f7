"""Candidate effects a declared model may lack: one class per effect.

Each class owns everything about its effect:

* ``propose(p, context)`` (class method): the candidates of this kind for profile ``p``;
* ``profile(p, values)``: the extended profile (new free parameters, ties, states, inputs), a plain
  profile; with the added parameters at their null value it has the same outputs as ``p``;
* ``pseudo()``: the pseudo-input channels it needs, as descriptions that
  :mod:`identify.model.pseudo_inputs` rebuilds from any run (so a refined profile works on plain
  measured runs with every command); ``runs(runs)`` adds them (a delay shifts its input instead);
* ``score_columns(fitting, p)``: its score-test columns when they are not the output sensitivities
  of its parameters (``linear = False``: the delay's response to ``-du/dt``);
* ``estimate(fitting, p, noise, hint, bounds)``: its fit(s) as :class:`Fitted`, by default one
  re-fit with the loop's estimator (the delay searches tau by profile likelihood and also fits a
  lag); ``bounds=False``: fits to rank, whose standard errors come when asked (:meth:`Fitted.bounded`);
* ``revisit(fitting, p, result, noise, steps)`` (class method): a last look at the final model
  once the loop has ended (the delay searches each of its delays again among the later effects).

A candidate is handed a :class:`~identify.refine.fitting.Fitting` (refit, residuals, input
response, cached predictions), never the loop. ``KIND_CLASSES`` maps a kind's name to its class;
adding an effect is adding one class here and its name there (docs/architecture.md). The loop
(:mod:`identify.refine.loop`) knows no kind.

=============  ==============  ===============================================================
kind           target          added
=============  ==============  ===============================================================
derivative     ``M_p``         a structurally zero A or B entry of a dynamic equation freed
delay          input           ``tau_<input>`` (s): the input shifted in time (``meta.delays``)
lag            input           state ``<input>_lag``, ``dx/dt = k (u - x)``, the input's B
                               entries moved onto it; ``k_<input>_lag`` (1/s) = 1/tau
sensor_lag     output          state ``<y>_sensor``, ``dx/dt = k (y - x)``, measured ``y`` = x
                               (a first-order filter on the measurement: gyro, vane, data
                               system); ``k_<y>_sensor`` (1/s) = 1/tau
bias           output          pseudo-input ``one``; ``bias_<y>`` on ``"<y>:one"``
drift          output          pseudo-input ``t`` (s from run start); ``drift_<y>`` on ``"<y>:t"``
scale          output          ``sf_<y>`` on ``"<y>:<y>"``: measured = (1 + sf) x
nonlinear      ``M:q_absq``    pseudo-input from measured channels with a physical reason
                               (``q_absq`` = q|q| of the equation's own state, ``eta_sq``,
                               ``q_x_eta`` with a declared input) and a B entry ``M_q_absq``
periodic       output          pseudo-inputs ``cos_<y>``, ``sin_<y>`` at frequency f (phase per
                               run from the measured output); ``a_cos_<y>``, ``a_sin_<y>``
=============  ==============  ===============================================================
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from ..data.runs import Run
from ..errors import EstimationError, ProfileError, PseudostepError, SimulationError
from ..model import pseudo_inputs as pi
from ..model.linear import LinearModel
from ..model.profile import Profile
from ..model.pseudo_inputs import delay_run
from .diagnostics import block_basis
from .noise import line_frequency


# a sensor's own filter (a rate gyro, a vane, an anti-aliasing filter) is fast beside the aircraft:
# a fitted "sensor lag" slower than this stands in for missing dynamics of the aircraft
MAX_SENSOR_LAG = 0.5  # s
# states refine adds as filters (an input's lag, a sensor's): no derivative or nonlinear term of theirs
FILTER_STATES = ("_lag", "_sensor")
# a calibrated sensor's scale-factor error is a few per cent; beyond this a fitted "scale factor" is
# absorbing missing dynamics (seen: -50 % on a rotor-tilt output standing in for a control delay)
MAX_SCALE_ERROR = 0.3
SCREENED = 2  # local minima of a delay's linearised profile re-fitted before its search


@dataclass
class Fitted:
    """One fit of a candidate: the fitted ``profile``, the estimator's ``result``, the new
    ``parameters`` ({name: {"value", "std"}}) and the ``kind`` fitted. ``finish``: where the fit was
    made to rank options (the likelihood to the search's precision, no coloured-residual bounds),
    how to complete it; :meth:`bounded` does (the loop asks only for the options it checks: the
    likeliest that passes ends the try, and the rest's bounds would cost a sandwich each for nothing)."""

    profile: Profile
    result: object
    parameters: dict
    kind: str
    finish: object = None  # () -> Fitted with its bounds; None: it has them

    def bounded(self) -> "Fitted":
        return self if self.finish is None else self.finish()


def refitted(fitting, ext_p: Profile, p: Profile, names, kind: str, bounds: bool = True) -> Fitted:
    """One re-fit of ``ext_p`` (``fitting.refit``) as a :class:`Fitted` with ``names``' parameters:
    with its bounds, or (``bounds=False``) a fit to rank options, completed when asked by the fit
    with bounds from the same start (not from the ranking fit: a filter-error fit restarted there
    can end at another optimum of its noise likelihood, and the fit checked must be the one the
    estimator gives)."""
    new_p, result = fitting.refit(ext_p, p, bounds=bounds)
    return Fitted(new_p, result, parameters_of(result, names), kind,
                  None if bounds else lambda: refitted(fitting, ext_p, p, names, kind))

@dataclass
class Context:
    """What proposing candidates needs besides the profile: the fit ``runs`` (raw), their
    ``residuals`` (N_r, ny) under the current model, ``dt`` s, the periodic search's ``f_min`` Hz
    and known ``frequencies`` Hz, and ``products`` (state x input nonlinear terms)."""

    runs: list[Run]
    residuals: list[np.ndarray]
    dt: float
    f_min: float = 0.5
    frequencies: tuple = ()
    products: bool = True
    kinds: tuple = ()
    held: tuple = ()  # parameters held because the estimator cannot determine them (still dynamics)


@dataclass(eq=False)
class Candidate:
    """Base: a named extension of a profile (see the module docstring)."""

    kind = "base"
    complexity = 0  # 1: ranked below the simpler explanations (nonlinear terms)
    linear = True  # score columns = output sensitivities of ``params`` at their null values
    # its column is what the residual noise model's fit removes from each run first (a mean, a
    # trend): in that model's metric too it is tested as in a model fitted without its own fit
    removed_by_noise_fit = False
    # kinds that explain the same residual to first order (an input's lag, a sensor's lag): when
    # this one is chosen, the most significant of them is fitted too and the likelier kept
    rivals = ()

    target: str
    params: list[str]
    n_tests: int = 1  # how many hypotheses choosing this candidate stands for (multiple testing)
    spec: dict = field(default_factory=dict)
    null_dof: int | None = None  # degrees of freedom of the null distribution if not len(params)

    @property
    def name(self) -> str:
        return f"{self.kind}:{self.target}"

    @classmethod
    def propose(cls, p: Profile, context: Context) -> list["Candidate"]:
        return []

    def as_rival(self) -> "Candidate":
        """The candidate fitted when this one is another's rival (by default itself)."""
        return self

    def null_values(self) -> dict[str, float]:
        return {k: 0.0 for k in self.params}

    def profile(self, p: Profile, values: dict[str, float] | None = None) -> Profile:
        raise NotImplementedError

    def pseudo(self) -> dict[str, dict]:
        """``{channel: description}`` of the pseudo-inputs it adds (see :mod:`identify.model.pseudo_inputs`)."""
        return {}

    def runs(self, runs: list[Run]) -> list[Run]:
        specs = self.pseudo()
        return [r.with_channels({n: pi.channel(n, s, r) for n, s in specs.items() if n not in r.channels})
                if specs else r for r in runs]

    def apply(self, p: Profile, runs: list[Run], values: dict[str, float] | None = None):
        return self.profile(p, values), self.runs(runs)

    def score_columns(self, fitting, p: Profile) -> list[np.ndarray] | None:
        """Per fit run (N_r, ny, q) columns for a candidate that is not ``linear``."""
        return None

    def estimate(self, fitting, p: Profile, noise, hint=None, bounds: bool = True) -> list[Fitted]:
        """Its fits, the more likely first: one re-fit of the extended profile (:func:`refitted`),
        the parameters with the estimator's bounds (``bounds=False``: when asked)."""
        return [refitted(fitting, self.profile(p), p, self.params, self.kind, bounds)]

    @classmethod
    def revisit(cls, fitting, p: Profile, result, noise, steps: list) -> tuple:
        """``(profile, result)`` after a last look at the final model ``p`` (fitted as ``result``)
        by the kind whose ``steps`` were accepted; by default nothing changes."""
        return p, result

    def implausible(self, params: dict[str, dict]) -> str:
        """Why the fitted ``params`` ({name: {"value", "std"}}) are physically implausible for
        this effect ('' if they are not): a statistically significant but unphysical value means
        the effect stands in for another one the model lacks."""
        return ""

    def to_dict(self) -> dict:
        return {"effect": self.kind, "target": self.target, "params": list(self.params),
                **{k: v for k, v in self.spec.items() if not k.startswith("_")}}


def _add(p: Profile, *, free=None, ties=None, inputs=None, states=None, meta=None, pseudo=None) -> Profile:
    meta = {**p.meta, **(meta or {})}
    if pseudo:  # how to rebuild each pseudo-input from a run (and which inputs are not controls)
        meta["pseudo_inputs"] = {**pi.specs(p), **pseudo}
    return replace(p, free={**p.free, **(free or {})}, ties={**p.ties, **(ties or {})},
                   inputs={**p.inputs, **(inputs or {})}, states={**p.states, **(states or {})}, meta=meta)


def _values(c: Candidate, values):
    return {**c.null_values(), **(values or {})}


def extend_all(p: Profile, candidates: list[Candidate]) -> tuple[Profile, list[Candidate]]:
    """One profile holding every candidate (each at its null value) that only *adds* to ``p``
    (free parameters, ties, inputs, meta tables), and the candidates that could be built: the
    score test of all of them from one sensitivity computation. Built as one union, validated once."""
    free, ties, inputs, meta = dict(p.free), dict(p.ties), dict(p.inputs), dict(p.meta)
    built = []
    for c in candidates:
        try:
            q = c.profile(p)
        except ProfileError:
            continue  # a candidate that cannot be built on this profile is not tested
        free.update(q.free)
        ties.update(q.ties)
        inputs.update(q.inputs)
        for key, value in q.meta.items():  # delays, periodic, pseudo_inputs: {name: value}
            meta[key] = {**dict(meta.get(key, {})), **value} if isinstance(value, dict) else value
        built.append(c)
    return replace(p, free=free, ties=ties, inputs=inputs, meta=meta), built


def prepare_runs(profile: Profile, runs: list[Run]) -> list[Run]:
    """Runs as ``profile`` needs them (delays applied, pseudo-inputs added): :func:`identify.model.pseudo_inputs.prepare`."""
    return pi.prepare(profile, runs)


# -- the kinds -------------------------------------------------------------------------------------
def _dynamic_rows(p: Profile, held=()) -> list[int]:
    """Rows of A/B with a free parameter (the dynamic equations), lag states excepted: an equation
    whose every entry is fixed (theta_dot = q) is kinematics, known exactly. A parameter ``held``
    only because the estimator cannot determine it (FR's gates: X_u of the pitch case) still makes
    its equation dynamics: held out of the catalogue, an undeclared X_eta there went untested."""
    rows = {e.row for name in [*p.free, *held] for e, _ in p.parameter_entries(name) if e.matrix in "AB"}
    return [i for i in sorted(rows) if not p.state_names[i].endswith(FILTER_STATES)]


def _controls(p: Profile) -> list[str]:
    """The declared inputs (not pseudo-inputs), without a lag already on them."""
    pseudo = pi.specs(p)
    return [u for u in p.inputs if u not in pseudo and f"{u}_lag" not in p.states]


def _measured_states(p: Profile, runs: list[Run]) -> list[str]:
    """States measured as an output of their own name (also through a sensor lag refine added)."""
    return [s for s in p.states if s in p.outputs and p.output_terms(s) in ({s: 1.0}, {f"{s}_sensor": 1.0})
            and all(s in r.channels for r in runs)]


class Derivative(Candidate):
    """Free a structurally zero A or B entry (``target`` is the entry name, e.g. ``M_p``)."""

    kind = "derivative"

    def __init__(self, entry: str):
        super().__init__(entry, [entry])

    @classmethod
    def propose(cls, p, context):
        taken = {(e.matrix, e.row, e.col) for name in p.parameters for e, _ in p.parameter_entries(name)}
        states = [j for j, s in enumerate(p.state_names) if not s.endswith(FILTER_STATES)]
        inputs = [p.input_names.index(u) for u in _controls(p)]
        return [cls(p.entry_name(m, i, j)) for i in _dynamic_rows(p, context.held)
                for m, cols in (("A", states), ("B", inputs)) for j in cols if (m, i, j) not in taken]

    def profile(self, p, values=None):
        return _add(p, free={self.target: _values(self, values)[self.target]})


class Delay(Candidate):
    """Pure time delay on an input (``tau_<input>`` in s), applied by shifting the input channel.

    Not linear in tau: its score column is dy/dtau at tau = 0, the response to ``-du/dt``. When
    chosen it is estimated by a profile-likelihood search over tau (ML re-fit at each tau) and a
    first-order :class:`Lag` is fitted too (to first order a lag and a delay are the same,
    ``1 - tau s``): both fits are returned, the more likely first."""

    kind = "delay"
    linear = False
    rivals = ("sensor_lag",)

    def __init__(self, input_name: str, tau: float = 0.0, lag: bool = True, search: bool = True):
        super().__init__(input_name, [f"tau_{input_name}"], spec={"tau": tau, "_lag": lag, "_search": search})

    @classmethod
    def propose(cls, p, context):
        delays = dict(p.meta.get("delays", {}))
        kinds = set(context.kinds or ("delay", "lag"))
        return [cls(u, lag="lag" in kinds, search="delay" in kinds) for u in _controls(p) if u not in delays]

    def profile(self, p, values=None):
        tau = (values or {}).get(self.params[0], self.spec["tau"])
        return _add(p, meta={"delays": {**dict(p.meta.get("delays", {})), self.target: float(tau)}})

    def as_rival(self):
        """Beside a sensor's lag, the input's lag: the same first-order shape, one re-fit instead of
        the delay's search (the delay itself where lags are not in the catalogue)."""
        return Delay(self.target, lag=True, search=False) if self.spec["_lag"] else self

    def runs(self, runs, tau: float | None = None):
        tau = self.spec["tau"] if tau is None else tau
        return [delay_run(r, self.target, tau) for r in runs]

    def apply(self, p, runs, values=None):
        tau = (values or {}).get(self.params[0], self.spec["tau"])
        return self.profile(p, {self.params[0]: tau}), self.runs(runs, tau)

    def score_columns(self, fitting, p):
        return [d[:, :, None] for d in fitting.input_response(p, self.target, lambda u, dt: -np.gradient(u, dt))]

    @classmethod
    def revisit(cls, fitting, p, result, noise, steps):
        """A delay found early was searched without the effects found after it (the demo: 0.104 s
        for a 0.1 s delay, 5 standard errors off, before the other cyclic's delay was added): with
        more than one delay accepted, search each again in the final model, the others held, and
        record the new estimate in its step."""
        delays_found = [s for s in steps if s.effect == cls.kind]
        if len(delays_found) < 2:
            return p, result
        for step in delays_found:
            delays = dict(p.meta["delays"])
            tau = delays.pop(step.target)
            without = replace(p, meta={**p.meta, "delays": delays})
            again = cls(step.target, lag=False)
            again.spec["_local"] = True  # near its first estimate: no screening of [0, tau_max] again
            found = again.estimate(fitting, without, noise, hint=tau)[0]
            if noise.cost(fitting.residuals(found.profile)) <= noise.cost(fitting.residuals(p)):
                p, result, step.parameters = found.profile, found.result, found.parameters
            fitting.say(f"delay on {step.target} searched again in the final model: {tau:.4g} -> "
                        f"{step.parameters[f'tau_{step.target}']['value']:.4g} s")
        return p, result

    def estimate(self, fitting, p, noise, hint=None, bounds=True):
        options = []
        dt = fitting.dt
        if self.spec["_search"]:
            # no delay is the model already fitted (p itself, unless searched again in a final model that
            # was fitted with this delay): its cost needs no re-fit
            fits: dict[float, tuple] = {} if self.spec.get("_local") else \
                {0.0: (0.5 * noise.cost(fitting.residuals(p)), p, None)}

            def at(tau: float):
                # on a grid of a thousandth of a sample: far inside any delay's statistical error, and
                # parabolas that only shuffle the last digits re-use their fits
                tau = float(np.clip(round(tau / dt, 3) * dt, 0.0, fitting.tau_max))
                key = round(tau, 9)
                if key not in fits:
                    # warm start from the nearest delay fitted so far, its noise estimate too: a few
                    # iterations, not twenty
                    _, start, near = fits[min(fits, key=lambda k: abs(k - key))] if fits else (0, p, None)
                    try:
                        prof, res = fitting.refit(self.profile(start, {self.params[0]: tau}), p, bounds=False,
                                                  start=near)
                        fits[key] = (0.5 * noise.cost(fitting.residuals(prof)), prof, res)
                    except (EstimationError, SimulationError):  # a delay whose fit diverges is not the likeliest one
                        fits[key] = (math.inf, start, None)
                return fits[key]

            # the profile likelihood in the metric of the test's noise model (under turbulence the
            # white one is biased: 0.088 s for a 0.1 s delay, 10 standard errors off), from the
            # whole-sample delay the linearised profile prefers (a delay searched again: its estimate)
            starts = [hint or 0.0] if self.spec.get("_local") else _screen(fitting, p, noise, self.target)
            tau = _search_delay(lambda t: at(t)[0], min(starts, key=lambda t: at(t)[0]), dt, fitting.tau_max)
            if not math.isfinite(at(tau)[0]):
                raise EstimationError(f"delay on '{self.target}': the fit diverged at every delay tried")
            # the bound from the curvature (central difference, shifted off the bound tau = 0)
            h = max(dt / 2, 0.05 * tau)
            c = tau if tau >= h else h
            curv = (at(c + h)[0] - 2 * at(c)[0] + at(c - h)[0]) / h ** 2
            # a neighbour whose fit diverged leaves the curvature undetermined: no bound, not zero
            std = 1 / math.sqrt(curv) if math.isfinite(curv) and curv > 0 else math.inf

            def finish(tau=tau, h=h, c=c, curv=curv, std=std) -> Fitted:
                # the search's fit converged fully, with its bounds; the standard error includes the
                # other parameters' errors, the step's significance (Wald) stays judged by the
                # curvature, in the metric of the test that chose it
                prof, res = fitting.refit(at(tau)[1], p, start=at(tau)[2])
                total = std if not math.isfinite(std) else \
                    _with_estimate_error(fitting, noise, prof, res, at(c + h)[1], at(c - h)[1], 2 * h, curv)
                return Fitted(prof, res, {self.params[0]: {"value": tau, "std": total, "std_profile": std}}, "delay")

            options.append(finish() if bounds else Fitted(at(tau)[1], at(tau)[2], {self.params[0]: {
                "value": tau, "std": std, "std_profile": std}}, "delay", finish))
        if self.spec["_lag"]:
            tau0 = options[0].parameters[self.params[0]]["value"] if options else 0.1
            try:
                options += Lag(self.target, k=1.0 / max(tau0, 2 * dt)).estimate(fitting, p, noise, bounds=bounds)
            except PseudostepError:
                pass  # a lag that diverges or cannot be fitted is not the effect
        if not options:
            raise EstimationError(f"neither a delay nor a lag on '{self.target}' could be fitted")
        return sorted(options, key=lambda o: noise.cost(fitting.residuals(o.profile)))


def _with_estimate_error(fitting, noise, prof, res, plus, minus, step: float, curv: float) -> float:
    """Standard error of a delay from the profile search, including the other parameters' errors.

    The curvature of the profile gives ``1 / curv`` only when each re-fit minimises the cost the
    profile is drawn in (ML in the tests' metric). Another estimator (FDEE: an equation error in
    the frequency domain) leaves errors in the derivatives that this cost would not, and the delay
    that fits best moves with them: BO 105, 0.08 s on theta_s, refine with FDEE scattered 0.0071 s
    over 12 noise draws where the curvature said 0.0014 s. Linearised, with ``v`` the whitened
    residual's derivative along the search path and ``J`` its derivative in the fitted parameters
    (covariance ``C`` from the estimator), ``var = 1/curv + (v'J C J'v) / curv^2``; for ML
    ``v'J = 0`` at the optimum and the bound is the curvature's. (The correlation between the
    estimator's errors and the residual noise is neglected.)

    ``J`` comes from one computation of the output sensitivities at the fit, whitened, with the
    nuisance (initial states, zero shifts) projected out as a re-fit in that metric removes it (a
    central difference of two predictions per parameter cost 7 s a delay on the 37-parameter BO 105)."""
    def white(p_):
        return np.concatenate([noise.whiten(e).ravel() for e in fitting.residuals(p_)])

    v = (white(plus) - white(minus)) / step
    free = [i for i, n in enumerate(res.names) if n in prof.free and np.isfinite(res.std[i]) and res.std[i] > 0]
    if not free:
        return 1 / math.sqrt(curv)
    ev = fitting.prediction(prof)
    evj = fitting.sensitivities(prof, ev.runs, ev)
    cols = [prof.free_names.index(res.names[i]) for i in free]
    J = []
    for d, nu in zip(evj.dy, evj.nuisance):  # each run's own nuisance, re-fitted at every parameter value
        Jr, Nr = (noise.whiten(x).reshape(-1, x.shape[2]) for x in (d[:, :, cols], nu))
        J.append(Jr - Nr @ np.linalg.lstsq(Nr, Jr, rcond=None)[0])
    vJ = -(v @ np.concatenate(J))  # the residual falls along the prediction's sensitivity
    C = res.parameter_covariance()[np.ix_(free, free)]
    extra = float(vJ @ C @ vJ) / curv ** 2
    return math.sqrt(1 / curv + extra) if math.isfinite(extra) else math.inf


def _screen(fitting, p: Profile, noise, input_name: str) -> list[float]:
    """The ``SCREENED`` whole-sample delays in [0, ``tau_max``] that are local minima of least
    linearised profile cost, where the search's re-fits start: the residual of ``p`` with the
    input shifted by k samples (the model's response to ``u(t - k dt) - u(t)`` subtracted), less
    its projection on the whitened sensitivities of the model's parameters and nuisance (one
    Gauss-Newton re-fit), in the noise model's metric.

    One prediction of one input per sample instead of a grid of full re-fits, and at every sample:
    with step inputs and outputs that feel the input at once (accelerations), the profile is far
    from smooth, a narrow notch at the true whole-sample delay between interpolated ones (BO 105,
    0.05 s on theta_0: cost 21547 there, 34095 and 34981 one sample either side, 23200 at no
    delay); a coarse grid of re-fits and parabolas stepped over it and returned 0.005 s. The
    linearisation about the model fitted without the delay (its derivatives bent to absorb it)
    keeps the notch but not the level (there 27832 at 0.05 s, 25375 at none): local minima, each
    re-fitted, not the least."""
    ev = fitting.prediction(p)
    evj = fitting.sensitivities(p, ev.runs, ev)
    Q = block_basis([noise.whiten(d) for d in evj.dy], [noise.whiten(nu) for nu in evj.nuisance])
    e0 = np.concatenate([noise.whiten(e).ravel() for e in ev.residuals])

    def cost(k: int) -> float:
        if k == 0:
            r = e0
        else:
            shifted = fitting.input_response(p, input_name, lambda u, _dt: np.r_[np.full(k, u[0]), u[:-k]][:len(u)] - u)
            r = e0 - np.concatenate([noise.whiten(x).ravel() for x in shifted])
        return float(r @ r - np.sum((Q.T @ r) ** 2))

    costs = np.array([cost(k) for k in range(int(fitting.tau_max / fitting.dt + 1e-9) + 1)])
    padded = np.r_[np.inf, costs, np.inf]
    minima = np.flatnonzero((costs <= padded[:-2]) & (costs <= padded[2:]))
    return [fitting.dt * k for k in sorted(minima, key=lambda k: costs[k])[:SCREENED]]


def _search_delay(cost, tau0: float, dt: float, tau_max: float) -> float:
    """Minimise ``cost(tau)`` over [0, tau_max] near ``tau0``: the best of ``tau0`` and the whole
    samples either side of it, then successive parabolas through three re-fits around the best
    point, a sample apart at first, until one points within a hundredth of a sample of a point
    already fitted."""
    k = round(tau0 / dt)
    grid = np.unique(np.clip([tau0, (k - 1) * dt, k * dt, (k + 1) * dt], 0.0, tau_max))
    tau = float(min(grid, key=cost))
    h, seen = dt, list(grid)
    for _ in range(6):
        pts = np.clip([tau - h, tau, tau + h], 0.0, tau_max)
        seen += list(pts)
        vals = [cost(t) for t in pts]
        with warnings.catch_warnings():  # repeated points at the bounds: the fallback handles it
            warnings.simplefilter("ignore", np.exceptions.RankWarning)
            a, b, _ = np.polyfit(pts, vals, 2)
        new = -b / (2 * a) if a > 0 else pts[int(np.argmin(vals))]
        new = float(np.clip(new, max(tau - 2 * h, 0.0), min(tau + 2 * h, tau_max)))
        done = min(abs(new - t) for t in seen) < dt / 100  # well inside the statistical error of any usable delay
        tau, h = new, max(dt / 10, min(h, 2 * abs(new - tau)))
        if done:
            break
    # the best point evaluated (the parabola may overshoot on a rough cost)
    return float(min(seen + [tau], key=cost))


class Lag(Candidate):
    """First-order lag between an input and the model: new state ``<input>_lag`` with
    ``d(lag)/dt = k (u - lag)``; every B entry of the input moves onto the lag state. Proposed
    through :class:`Delay` (they share the score test)."""

    kind = "lag"
    linear = False

    def __init__(self, input_name: str, k: float = 10.0):
        self.state = f"{input_name}_lag"
        super().__init__(input_name, [f"k_{self.state}"], spec={"k": k})

    def null_values(self):
        return {self.params[0]: self.spec["k"]}

    def profile(self, p, values=None):
        u, x = self.target, self.state
        if u not in p.inputs:
            raise ProfileError(f"lag: '{u}' is not an input of the profile")
        j = p.input_names.index(u)
        new_p = replace(p, states={**p.states, x: p.inputs[u]})

        def move(entry: str) -> str:
            if ":" in entry:
                return entry
            e = p.parse_entry(entry)
            return f"{p.equation(p.state_names[e.row])}_{x}" if e.matrix == "B" and e.col == j else entry

        free, fixed, ties = {}, {}, {}
        for table, out in ((p.free, free), (p.fixed, fixed)):
            for name, value in table.items():
                if name in p.ties:
                    out[name] = value
                    ties[name] = {move(e): c for e, c in p.ties[name].items()}
                else:
                    out[move(name)] = value
        k = self.params[0]
        free[k] = float(_values(self, values)[k])
        ties[k] = {f"{x}_{x}": -1.0, f"{x}_{u}": 1.0}
        return replace(new_p, free=free, fixed=fixed, ties=ties)


class SensorLag(Candidate):
    """First-order lag of a measurement, ``tau dy_m/dt = y - y_m``: the dynamics of the sensor
    and its data system (a rate gyro's or a vane's filter, an anti-aliasing filter, a time skew
    between channels, which a lag matches to first order). New state ``<y>_sensor`` (``k`` =
    1/tau, 1/s) driven by the state ``y``; the output ``y`` becomes that state.

    Flight-test data-compatibility practice treats each measured channel's lag as its own
    effect. Without it a sensor's lag is explained where the catalogue can, as a lag or delay on
    the input (``benchmarks/refine_reallike.py``: a 0.08 s lag on the q gyro was taken for a lag
    on eta in 32 of 40 realisations). The two differ in which outputs they move: an input lag
    delays every output's response to that input, a sensor lag only its own output's.

    Not linear in k (the null is k = infinity): its score column is ``dy_m/dtau`` at tau = 0,
    ``-dy/dt`` on its own output (zero on the others), through the estimator's own prediction
    (:func:`_first_order_sensor_columns`). Proposed for an output that is a state measured as
    itself and no output-equation parameter of its own yet (a scale factor)."""

    kind = "sensor_lag"
    linear = False
    rivals = ("delay",)

    def __init__(self, output: str, k: float = 20.0):
        self.state = f"{output}_sensor"
        super().__init__(output, [f"k_{self.state}"], spec={"k": k})

    @classmethod
    def propose(cls, p, context):
        return [cls(y) for y in _sensor_outputs(p) if all(y in r.channels for r in context.runs)]

    def null_values(self):
        return {self.params[0]: self.spec["k"]}

    def profile(self, p, values=None):
        y, x = self.target, self.state
        if y not in p.states or y not in p.outputs or p.output_terms(y) != {y: 1.0}:
            raise ProfileError(f"sensor lag: '{y}' is not a state measured as itself")
        k = self.params[0]
        return replace(p, states={**p.states, x: p.states[y]}, output_defs={**p.output_defs, y: {x: 1.0}},
                       free={**p.free, k: float(_values(self, values)[k])},
                       ties={**p.ties, k: {f"{x}_{x}": -1.0, f"{x}_{y}": 1.0}})

    def score_columns(self, fitting, p):
        return _first_order_sensor_columns(fitting, p)[self.target]

    def estimate(self, fitting, p, noise, hint=None, bounds=True):
        tau0 = float(np.ravel(hint)[0]) if hint is not None and np.size(hint) else 0.0
        if tau0 < 0:
            # the score is two-sided; a lag is not: the output leads the model (seen: theta beside a
            # lagging q gyro, the attitude then looks early), and no filter makes a measurement early
            raise EstimationError(f"the residual asks for '{self.target}' to lead the model (linearised tau "
                                  f"{tau0:.3g} s < 0): no sensor lag")
        # the score's linearised tau starts the fit (a few samples at least: k of a vanishing lag is
        # far out on a flat likelihood)
        tau0 = min(max(tau0, 2 * fitting.dt), MAX_SENSOR_LAG) if math.isfinite(tau0) else 2 * fitting.dt
        start = SensorLag(self.target, k=1.0 / tau0)
        return [refitted(fitting, start.profile(p), p, self.params, self.kind, bounds)]

    def implausible(self, params):
        k = params[self.params[0]]["value"]
        if not k > 1.0 / MAX_SENSOR_LAG:
            what = "negative" if k <= 0 else f"{1.0 / k:.3g} s"
            return (f"a sensor lag of {what} on '{self.target}' (k = {k:.3g} 1/s) is no sensor's filter (limit "
                    f"{MAX_SENSOR_LAG:g} s): it stands in for dynamics the model lacks")
        return ""


def _sensor_outputs(p: Profile) -> list[str]:
    """Outputs a sensor lag can be added to: states measured as themselves, no lag yet and no
    parameter on their output equation (its entries would clash with the score's surrogate)."""
    taken = {e.row for name in p.parameters for e, _ in p.parameter_entries(name) if e.matrix in "CD"}
    return [y for j, y in enumerate(p.outputs) if y in p.states and p.output_terms(y) == {y: 1.0}
            and f"{y}_sensor" not in p.states and j not in taken]


def _first_order_sensor_columns(fitting, p: Profile) -> dict[str, list[np.ndarray]]:
    """Per output of :func:`_sensor_outputs`, per fit run (N_r, ny, 1): ``dy_m/dtau`` of a sensor
    lag at tau = 0 as the loop's estimator predicts it. To first order the lag measures
    ``y - tau dy/dt`` and ``dy/dt = A_y x + B_y u`` (the state's own equation at the current fit):
    a surrogate profile with, per output, a parameter ``tau`` tied to ``"<y>:<term>" = -A_y, -B_y``
    (linear, zero at the null) gives that column from the estimator's own sensitivities, the
    model's states as it predicts them (a simulation, or a filter's, whose innovations the
    derivative of the measured output would not describe). One computation for every output,
    cached per fitted profile."""
    key = ("sensor_lag columns", p.to_toml())
    if key not in fitting.cache:
        model = LinearModel(p)
        outputs = _sensor_outputs(p)
        ties = {}
        for y in outputs:
            i = p.state_names.index(y)
            row = [(s, model.A[i, c]) for c, s in enumerate(p.state_names)] + \
                  [(u, model.B[i, c]) for c, u in enumerate(p.input_names)]
            ties[f"tau1_{y}_sensor"] = {f"{y}:{term}": -float(v) for term, v in row if v != 0.0}
        ties = {k: v for k, v in ties.items() if v}
        columns = {}
        if ties:
            ext = replace(p, free={**p.free, **{k: 0.0 for k in ties}}, ties={**p.ties, **ties})
            ev = fitting.prediction(p)
            dy = fitting.sensitivities(ext, ev.runs, ev).dy
            first = len(p.free)
            for c, name in enumerate(ties):
                y = name[len("tau1_"):-len("_sensor")]
                columns[y] = [d[:, :, first + c:first + c + 1] for d in dy]
        fitting.cache[key] = {y: columns.get(y, [np.zeros((len(r), len(p.outputs), 1)) for r in fitting.data["fit"]])
                              for y in outputs}
    return fitting.cache[key]


class OutputTerm(Candidate):
    """An output-equation entry ``"<y>:<term>"`` through a tie parameter, with an optional
    pseudo-input ``term`` described by ``channel`` (see :mod:`identify.model.pseudo_inputs`)."""

    prefix = ""
    term = ""
    description: dict | None = None
    unit = "1"

    def __init__(self, output: str):
        super().__init__(output, [f"{self.prefix}_{output}"])

    @classmethod
    def propose(cls, p, context):
        return [cls(y) for y in p.outputs if f"{cls.prefix}_{y}" not in p.parameters and cls.applies(p, y)]

    @classmethod
    def applies(cls, p: Profile, y: str) -> bool:
        return True

    def entry_term(self) -> str:
        return self.term

    def pseudo(self):
        return {self.term: self.description} if self.description else {}

    def profile(self, p, values=None):
        param, term = self.params[0], self.entry_term()
        pseudo = {k: v for k, v in self.pseudo().items() if k not in p.inputs}
        return _add(p, inputs={k: self.unit for k in pseudo}, pseudo=pseudo,
                    free={param: _values(self, values)[param]}, ties={param: {f"{self.target}:{term}": 1.0}})


class Bias(OutputTerm):
    """A bias common to all runs on an output (testable only without per-run zero shifts)."""

    kind, prefix, term, description, unit = "bias", "bias", "one", pi.constant(), "1"
    removed_by_noise_fit = True


class Drift(OutputTerm):
    """A linear drift of an output with the time from each run's start."""

    kind, prefix, term, description, unit = "drift", "drift", "t", pi.time(), "s"
    removed_by_noise_fit = True


class Scale(OutputTerm):
    """A scale-factor error of an output that is a state: measured = (1 + sf) x."""

    kind, prefix = "scale", "sf"

    @classmethod
    def applies(cls, p, y):
        return y in p.states and p.output_terms(y) == {y: 1.0}

    def entry_term(self):
        return self.target

    def implausible(self, params):
        sf = params[self.params[0]]["value"]
        if abs(sf) > MAX_SCALE_ERROR:
            return (f"a scale-factor error of {100 * sf:+.0f} % on '{self.target}' is beyond any "
                    f"calibration error (limit ±{100 * MAX_SCALE_ERROR:.0f} %): it stands in for an effect "
                    f"the model lacks")
        return ""


def bias(output: str) -> Bias:
    return Bias(output)


def drift(output: str) -> Drift:
    return Drift(output)


def scale(output: str) -> Scale:
    return Scale(output)


class Nonlinear(Candidate):
    """A term of measured channels (``a_absa`` = a|a|, ``a_sq`` = a^2, ``a_x_b`` = a b) as a
    pseudo-input with a B entry in ``equation``: target ``<equation>:<term>``; ``why`` the physical
    reason that ties the term to the equation (stated in the report)."""

    kind = "nonlinear"
    complexity = 1

    def __init__(self, equation: str, term: str, factors: tuple[str, ...], op: str, why: str = ""):
        super().__init__(f"{equation}:{term}", [f"{equation}_{term}"], spec={"term": term, "op": op, "why": why})
        self.equation, self.term, self.factors = equation, term, tuple(factors)

    @classmethod
    def propose(cls, p, context):
        """Terms with a physical reason, in every dynamic equation: the equation's own state x as
        x|x| (quadratic damping) and x^2 (an asymmetry), each declared control input u as u|u| and
        u^2 (a nonlinear control effectiveness) and (``context.products``) x u (a control
        effectiveness that varies with the equation's own state). Terms of other states
        (alpha|alpha| in the speed equation, q theta in X) have no such story there: not tried."""
        measured = set(_measured_states(p, context.runs))
        controls = [u for u in _controls(p) if all(u in r.channels for r in context.runs)]
        out = []
        for i in _dynamic_rows(p, context.held):
            x = p.state_names[i]
            eq = p.equation(x)
            terms = []
            if x in measured:
                terms += [(f"{x}_abs{x}", (x,), "absq", f"quadratic damping: {eq} in {x}|{x}|, its own state"),
                          (f"{x}_sq", (x,), "sq", f"asymmetry of {eq} in its own state {x}")]
            for u in controls:
                terms += [(f"{u}_abs{u}", (u,), "absq", f"control effectiveness of the declared input {u} nonlinear"),
                          (f"{u}_sq", (u,), "sq", f"control effectiveness of the declared input {u} asymmetric")]
                if context.products and x in measured:
                    terms.append((f"{x}_x_{u}", (x, u), "prod",
                                  f"effectiveness of the declared input {u} varies with {x}, the equation's own state"))
            for term, factors, op, why in terms:
                if term in p.inputs or f"{eq}_{term}" in p.parameters:
                    continue
                c = cls(eq, term, factors, op, why)
                try:
                    c.profile(p)
                except ProfileError:
                    continue  # the name would be ambiguous with an existing entry
                out.append(c)
        return out

    def pseudo(self):
        a = self.factors[0]
        if self.spec["op"] == "absq":
            return {self.term: pi.product([a, a], [False, True])}
        if self.spec["op"] == "sq":
            return {self.term: pi.product([a, a])}
        return {self.term: pi.product(self.factors)}

    def profile(self, p, values=None):
        pseudo = {} if self.term in p.inputs else self.pseudo()
        p2 = _add(p, inputs={k: "nonlinear" for k in pseudo}, pseudo=pseudo)
        p2.parse_entry(self.params[0])  # unambiguous or ProfileError
        return _add(p2, free={self.params[0]: _values(self, values)[self.params[0]]})


class Periodic(Candidate):
    """A sinusoidal disturbance at ``frequency`` Hz on an output: pseudo-inputs
    ``cos_<y>``/``sin_<y>`` = cos/sin(2 pi f t + phi_r), phi_r the phase of the measured output at f
    in run r (a disturbance's phase differs from run to run; the relative phase of the outputs
    does not), with coefficients ``a_cos_<y>`` (the amplitude) and ``a_sin_<y>``."""

    kind = "periodic"

    def __init__(self, output: str, frequency: float, n_tests: int = 1, n_runs: int = 1):
        # the phase is taken from each run's data: under the null the statistic has two degrees of
        # freedom per run (amplitude and phase), not two in all
        super().__init__(output, [f"a_cos_{output}", f"a_sin_{output}"], n_tests=n_tests,
                         spec={"frequency": float(frequency)}, null_dof=2 * n_runs)

    @classmethod
    def propose(cls, p, context):
        """One per output not yet holding one: at the first known frequency, else at the residual
        spectrum's most prominent line above ``f_min`` (counted as one test per frequency bin,
        twice for the sub-bin search)."""
        done = set(dict(p.meta.get("periodic", {})))
        n_runs = len(context.runs)
        n_bins = int(np.sum(np.fft.rfftfreq(min(len(e) for e in context.residuals), context.dt) > context.f_min))
        out = []
        for j, y in enumerate(p.outputs):
            if y in done:
                continue
            if context.frequencies:
                out.append(cls(y, context.frequencies[0], n_runs=n_runs))
                continue
            f = line_frequency([e[:, j] for e in context.residuals], context.dt, context.f_min)
            if np.isfinite(f):
                out.append(cls(y, f, n_tests=2 * max(n_bins, 1), n_runs=n_runs))
        return out

    def pseudo(self):
        y, f = self.target, self.spec["frequency"]
        return {f"cos_{y}": pi.sinusoid(y, f), f"sin_{y}": pi.sinusoid(y, f, quadrature=True)}

    def profile(self, p, values=None):
        v = _values(self, values)
        y = self.target
        pseudo = self.pseudo()
        return _add(p, inputs={k: "1" for k in pseudo}, pseudo=pseudo, free={k: v[k] for k in self.params},
                    ties={f"a_{w}_{y}": {f"{y}:{w}_{y}": 1.0} for w in ("cos", "sin")},
                    meta={"periodic": {**dict(p.meta.get("periodic", {})), y: self.spec["frequency"]}})


# the catalogue: kind -> class (a lag is proposed through Delay: they share one score test)
KIND_CLASSES = {"derivative": Derivative, "delay": Delay, "lag": Lag, "sensor_lag": SensorLag, "bias": Bias,
                "drift": Drift, "scale": Scale, "nonlinear": Nonlinear, "periodic": Periodic}
KINDS = tuple(KIND_CLASSES)


def catalogue(p: Profile, context: Context, kinds=KINDS) -> list[Candidate]:
    """Every candidate of ``kinds`` the profile does not already hold."""
    classes = list(dict.fromkeys(Delay if KIND_CLASSES[k] is Lag else KIND_CLASSES[k] for k in kinds))
    context = replace(context, kinds=tuple(kinds))
    return [c for cls in classes for c in cls.propose(p, context)]


__all__ = ["KINDS", "KIND_CLASSES", "Context", "Candidate", "Fitted", "refitted", "Derivative", "Delay", "Lag",
           "SensorLag", "OutputTerm", "Bias", "Drift", "Scale", "Nonlinear", "Periodic", "bias", "drift", "scale",
           "catalogue", "delay_run", "prepare_runs", "extend_all"]


def parameters_of(result, names) -> dict:
    """``{name: {"value", "std"}}`` of the ``names`` in an identification result."""
    return {k: {"value": float(result.theta[result.names.index(k)]),
                "std": float(result.std[result.names.index(k)])} for k in names}
