"""Catalogue of candidate effects a declared model may lack, as profile + run transformations.

Each candidate is a small object with a ``kind`` (from :data:`KINDS`), a ``target`` (the entry,
output, input or equation it acts on) and the ``params`` it adds. ``profile(p, values)`` returns the
extended profile (a plain profile: new free parameters, ties, states, pseudo-inputs);
``runs(runs)`` adds the pseudo-input channels (or shifts an input, for a delay) the extended
profile needs. Applying both to a fitted profile with the added parameters at their null value
leaves the model's outputs unchanged, so output sensitivities at that point are the candidate's
score-test columns. See ``docs/refine.md`` for the catalogue.

=============  ==============  ===============================================================
kind           target          added
=============  ==============  ===============================================================
derivative     ``M_p``         a structurally zero A or B entry freed (null value 0)
delay          input           ``tau_<input>`` (s): the input shifted in time (run transform;
                               recorded in the profile's ``meta.delays``)
lag            input           state ``<input>_lag``, ``dx/dt = k (u - x)``, the input's B
                               entries moved onto it; ``k_<input>_lag`` (1/s) = 1/tau
bias           output          pseudo-input ``one``; ``bias_<y>`` on ``"<y>:one"``
drift          output          pseudo-input ``t`` (s from run start); ``drift_<y>`` on ``"<y>:t"``
scale          output          ``sf_<y>`` on ``"<y>:<y>"``: measured = (1 + sf) x
nonlinear      ``M:q_absq``    pseudo-input from measured channels (``q_absq`` = q|q|,
                               ``q_sq`` = q^2, ``u_x_v`` = u v) with a B entry ``M_q_absq``
periodic       output          pseudo-inputs ``cos_<y>``, ``sin_<y>`` at frequency f (phase per
                               run from the measured output); ``a_cos_<y>``, ``a_sin_<y>``
=============  ==============  ===============================================================
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from itertools import combinations

import numpy as np

from ..data.runs import Run
from ..errors import ProfileError
from ..model.profile import Profile
from ..model.simulate import delay_inputs

KINDS = ("derivative", "delay", "lag", "bias", "drift", "scale", "nonlinear", "periodic")


@dataclass
class Candidate:
    """Base: a named extension. ``linear``: the model is linear in the added parameters at their
    null value (exact score columns from sensitivities); otherwise (delay, lag) the score column
    is supplied by the loop (the delay sensitivity ``-du/dt`` response)."""

    kind: str
    target: str
    params: list[str]
    linear: bool = True
    n_tests: int = 1  # how many hypotheses choosing this candidate stands for (multiple testing)
    spec: dict = field(default_factory=dict)
    null_dof: int | None = None  # degrees of freedom of the null distribution if not len(params)

    @property
    def name(self) -> str:
        return f"{self.kind}:{self.target}"

    def null_values(self) -> dict[str, float]:
        return {k: 0.0 for k in self.params}

    def profile(self, p: Profile, values: dict[str, float] | None = None) -> Profile:
        raise NotImplementedError

    def runs(self, runs: list[Run]) -> list[Run]:
        return list(runs)

    def apply(self, p: Profile, runs: list[Run], values: dict[str, float] | None = None):
        return self.profile(p, values), self.runs(runs)

    def to_dict(self) -> dict:
        return {"effect": self.kind, "target": self.target, "params": list(self.params),
                **{k: v for k, v in self.spec.items() if not k.startswith("_")}}


def _add(p: Profile, *, free=None, ties=None, inputs=None, states=None, meta=None) -> Profile:
    meta = dict(meta or {})
    if inputs:  # remembered so that later steps tell pseudo-inputs from controls
        meta["pseudo_inputs"] = list(dict.fromkeys(list(p.meta.get("pseudo_inputs", [])) + list(inputs)))
    return replace(p, free={**p.free, **(free or {})}, ties={**p.ties, **(ties or {})},
                   inputs={**p.inputs, **(inputs or {})}, states={**p.states, **(states or {})},
                   meta={**p.meta, **(meta or {})})


def _values(c: Candidate, values):
    return {**c.null_values(), **(values or {})}


class Derivative(Candidate):
    """Free a structurally zero A or B entry (``target`` is the entry name, e.g. ``M_p``)."""

    def __init__(self, entry: str):
        super().__init__("derivative", entry, [entry])

    def profile(self, p, values=None):
        return _add(p, free={self.target: _values(self, values)[self.target]})


class Delay(Candidate):
    """Pure time delay on an input (``tau_<input>`` in s), applied by shifting the input channel
    (linear interpolation; the first value held before the start)."""

    def __init__(self, input_name: str, tau: float = 0.0):
        super().__init__("delay", input_name, [f"tau_{input_name}"], linear=False, spec={"tau": tau})

    def profile(self, p, values=None):
        tau = _values(self, values).get(self.params[0], self.spec["tau"])
        return _add(p, meta={"delays": {**dict(p.meta.get("delays", {})), self.target: float(tau)}})

    def runs(self, runs, tau: float | None = None):
        tau = self.spec["tau"] if tau is None else tau
        return [delay_run(r, self.target, tau) for r in runs]

    def apply(self, p, runs, values=None):
        tau = _values(self, values).get(self.params[0], self.spec["tau"])
        return self.profile(p, {self.params[0]: tau}), self.runs(runs, tau)


def delay_run(run: Run, input_name: str, tau: float) -> Run:
    """``run`` with ``input_name`` replaced by u(t - tau)."""
    return run.with_channels({input_name: delay_inputs(run.time, run[input_name], tau)})


def apply_delays(profile: Profile, runs: list[Run]) -> list[Run]:
    """Shift the inputs of runs by the delays recorded in ``profile.meta['delays']``."""
    for name, tau in dict(profile.meta.get("delays", {})).items():
        runs = [delay_run(r, name, float(tau)) for r in runs]
    return runs


class Lag(Candidate):
    """First-order lag between an input and the model: new state ``<input>_lag`` with
    ``d(lag)/dt = k (u - lag)``; every B entry of the input moves onto the lag state."""

    def __init__(self, input_name: str, k: float = 10.0):
        self.state = f"{input_name}_lag"
        super().__init__("lag", input_name, [f"k_{self.state}"], linear=False, spec={"k": k})

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


class OutputTerm(Candidate):
    """An output-equation entry ``"<y>:<term>"`` through a tie parameter, with an optional
    pseudo-input channel built from each run."""

    def __init__(self, kind: str, output: str, param: str, term: str, unit: str | None = None,
                 channel=None, n_tests: int = 1, spec=None):
        super().__init__(kind, output, [param], n_tests=n_tests, spec=dict(spec or {}))
        self.term, self.unit, self.channel = term, unit, channel

    def profile(self, p, values=None):
        inputs = {self.term: self.unit} if self.unit is not None and self.term not in p.inputs else {}
        param = self.params[0]
        return _add(p, inputs=inputs, free={param: _values(self, values)[param]},
                    ties={param: {f"{self.target}:{self.term}": 1.0}})

    def runs(self, runs):
        if self.channel is None:
            return list(runs)
        return [r if self.term in r.channels else r.with_channels({self.term: self.channel(r)}) for r in runs]


def bias(output: str) -> OutputTerm:
    return OutputTerm("bias", output, f"bias_{output}", "one", "1", lambda r: np.ones(len(r)))


def drift(output: str) -> OutputTerm:
    return OutputTerm("drift", output, f"drift_{output}", "t", "s", lambda r: r.time - r.time[0])


def scale(output: str) -> OutputTerm:
    return OutputTerm("scale", output, f"sf_{output}", output)


class Nonlinear(Candidate):
    """A library term of measured channels (``a_absa`` = a|a|, ``a_sq`` = a^2, ``a_x_b`` = a b)
    as a pseudo-input with a B entry in ``equation``: target ``<equation>:<term>``."""

    def __init__(self, equation: str, term: str, factors: tuple[str, ...], op: str):
        super().__init__("nonlinear", f"{equation}:{term}", [f"{equation}_{term}"], spec={"term": term, "op": op})
        self.equation, self.term, self.factors = equation, term, factors

    def channel(self, run: Run) -> np.ndarray:
        a = run[self.factors[0]]
        if self.spec["op"] == "absq":
            return a * np.abs(a)
        if self.spec["op"] == "sq":
            return a * a
        return a * run[self.factors[1]]

    def profile(self, p, values=None):
        inputs = {} if self.term in p.inputs else {self.term: "nonlinear"}
        p2 = _add(p, inputs=inputs)
        p2.parse_entry(self.params[0])  # unambiguous or ProfileError
        return _add(p2, free={self.params[0]: _values(self, values)[self.params[0]]})

    def runs(self, runs):
        return [r if self.term in r.channels else r.with_channels({self.term: self.channel(r)}) for r in runs]


class Periodic(Candidate):
    """A sinusoidal disturbance at ``frequency`` Hz on an output: pseudo-inputs
    ``cos_<y>``/``sin_<y>`` = cos/sin(2 pi f t + phi_r), phi_r the phase of the measured output at f
    in run r (a disturbance's phase differs from run to run; the relative phase of the outputs
    does not), with coefficients ``a_cos_<y>`` (the amplitude) and ``a_sin_<y>``."""

    def __init__(self, output: str, frequency: float, n_tests: int = 1, n_runs: int = 1):
        # the phase is taken from each run's data: under the null the statistic has two degrees of
        # freedom per run (amplitude and phase), not two in all
        super().__init__("periodic", output, [f"a_cos_{output}", f"a_sin_{output}"], n_tests=n_tests,
                         spec={"frequency": float(frequency)}, null_dof=2 * n_runs)

    def profile(self, p, values=None):
        v = _values(self, values)
        y = self.target
        inputs = {f"{w}_{y}": "1" for w in ("cos", "sin")}
        return _add(p, inputs=inputs, free={k: v[k] for k in self.params},
                    ties={f"a_{w}_{y}": {f"{y}:{w}_{y}": 1.0} for w in ("cos", "sin")},
                    meta={"periodic": {**dict(p.meta.get("periodic", {})), y: self.spec["frequency"]}})

    def runs(self, runs):
        return [periodic_channels(r, self.target, self.spec["frequency"]) for r in runs]


def periodic_channels(run: Run, output: str, frequency: float) -> Run:
    """Add ``cos_<y>``, ``sin_<y>`` to a run, phased on the measured output at ``frequency``."""
    z = run[output]
    t = run.time - run.time[0]
    X = np.column_stack([np.ones_like(t), t])
    z = z - X @ np.linalg.lstsq(X, z, rcond=None)[0]
    w = 2 * np.pi * frequency
    phase = float(np.angle(np.sum(z * np.exp(-1j * w * t))))
    return run.with_channels({f"cos_{output}": np.cos(w * t + phase), f"sin_{output}": np.sin(w * t + phase)})


def apply_periodic(profile: Profile, runs: list[Run]) -> list[Run]:
    """Add the periodic pseudo-inputs recorded in ``profile.meta['periodic']`` to runs."""
    for y, f in dict(profile.meta.get("periodic", {})).items():
        runs = [periodic_channels(r, y, float(f)) for r in runs]
    return runs


def prepare_runs(profile: Profile, runs: list[Run]) -> list[Run]:
    """Everything a refined profile needs from raw runs: delays, pseudo-inputs ``one``, ``t``,
    nonlinear library terms and periodic channels, by the names the profile declares."""
    runs = apply_periodic(profile, apply_delays(profile, runs))
    out = []
    for r in runs:
        extra = {}
        for name in profile.inputs:
            if name in r.channels:
                continue
            if name == "one":
                extra[name] = np.ones(len(r))
            elif name == "t":
                extra[name] = r.time - r.time[0]
            else:
                term = _parse_library_term(name, r)
                if term is not None:
                    extra[name] = term
        out.append(r.with_channels(extra) if extra else r)
    return out


def _parse_library_term(name: str, run: Run):
    """The channel of a nonlinear library pseudo-input named as :class:`Nonlinear` names it."""
    if name.endswith("_sq") and name[:-3] in run.channels:
        return run[name[:-3]] ** 2
    if "_abs" in name:
        a, _, b = name.partition("_abs")
        if a == b and a in run.channels:
            return run[a] * np.abs(run[a])
    if "_x_" in name:
        a, _, b = name.partition("_x_")
        if a in run.channels and b in run.channels:
            return run[a] * run[b]
    return None


# -- the catalogue ------------------------------------------------------------------------------
def _measured_states(p: Profile, runs: list[Run]) -> list[str]:
    return [s for s in p.states if s in p.outputs and p.output_terms(s) == {s: 1.0}
            and all(s in r.channels for r in runs)]


def _base_inputs(p: Profile) -> list[str]:
    pseudo = set(p.meta.get("pseudo_inputs", []))
    return [u for u in p.inputs if u not in pseudo]


def catalogue(p: Profile, runs: list[Run], kinds=KINDS, nonlinear_products: bool = True) -> list[Candidate]:
    """Every candidate of ``kinds`` the profile does not already hold (periodic candidates come
    from the residual spectrum, see :func:`identify.refine.Refine`)."""
    kinds = set(kinds)
    out: list[Candidate] = []
    taken = {(e.matrix, e.row, e.col) for name in p.parameters for e, _ in p.parameter_entries(name)}
    lag_states = {s for s in p.states if s.endswith("_lag") and s[:-4] in p.inputs}
    dynamic = [s for s in p.states if s not in lag_states]
    base_inputs = _base_inputs(p)
    if "derivative" in kinds:
        for i, s in enumerate(p.state_names):
            if s in lag_states:
                continue
            for j, s2 in enumerate(p.state_names):
                if ("A", i, j) not in taken and s2 in dynamic:
                    out.append(Derivative(p.entry_name("A", i, j)))
            for j, u in enumerate(p.input_names):
                if ("B", i, j) not in taken and u in base_inputs and not _lagged(p, u):
                    out.append(Derivative(p.entry_name("B", i, j)))
    delays = dict(p.meta.get("delays", {}))
    for u in base_inputs:
        if u in delays or _lagged(p, u):
            continue
        if "delay" in kinds or "lag" in kinds:
            out.append(Delay(u))
    for y in p.outputs:
        if "bias" in kinds and f"bias_{y}" not in p.parameters:
            out.append(bias(y))
        if "drift" in kinds and f"drift_{y}" not in p.parameters:
            out.append(drift(y))
        if "scale" in kinds and f"sf_{y}" not in p.parameters and y in p.states \
                and p.output_terms(y) == {y: 1.0}:
            out.append(scale(y))
    if "nonlinear" in kinds:
        out += nonlinear_library(p, runs, products=nonlinear_products)
    return out


def _lagged(p: Profile, u: str) -> bool:
    return f"{u}_lag" in p.states


def nonlinear_library(p: Profile, runs: list[Run], products: bool = True) -> list[Nonlinear]:
    """x|x| and x^2 of every measured state and every input, and (``products``) pairwise products,
    each tried in every equation that has a free parameter (the dynamic equations)."""
    channels = _measured_states(p, runs) + [u for u in _base_inputs(p) if all(u in r.channels for r in runs)]
    terms = [(f"{a}_abs{a}", (a,), "absq") for a in channels] + [(f"{a}_sq", (a,), "sq") for a in channels]
    if products:
        terms += [(f"{a}_x_{b}", (a, b), "prod") for a, b in combinations(channels, 2)]
    free_rows = {e.row for name in p.free for e, _ in p.parameter_entries(name) if e.matrix in "AB"}
    equations = [p.equation(p.state_names[i]) for i in sorted(free_rows)
                 if not p.state_names[i].endswith("_lag")]
    out = []
    for eq in equations:
        for term, factors, op in terms:
            if term in p.inputs or f"{eq}_{term}" in p.parameters:
                continue
            c = Nonlinear(eq, term, factors, op)
            try:
                c.profile(p)
            except ProfileError:
                continue  # the name would be ambiguous with an existing entry
            out.append(c)
    return out


__all__ = ["KINDS", "Candidate", "Derivative", "Delay", "Lag", "OutputTerm", "Nonlinear", "Periodic",
           "bias", "drift", "scale", "catalogue", "nonlinear_library", "delay_run", "apply_delays",
           "periodic_channels", "apply_periodic", "prepare_runs"]
