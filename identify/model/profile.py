"""A priori model profiles: states, inputs, outputs and named derivatives in TOML.

A profile declares the linear model ``dx/dt = A x + B u`` through named derivatives. The equation
of state ``u, v, w, p, q, r`` is ``X, Y, Z, L, M, N``; any other state's equation carries the
state's own name. An entry of A is ``<equation>_<state>`` (``M_q``, ``theta_q``), an entry of B is
``<equation>_<input>`` (``M_theta_s``). Entries not named are structurally zero. A parameter is
either *free* (estimated; its value is the a priori guess) or *fixed* (known). A parameter that
acts on several entries at once (for example ``1/tau`` of an added lag, which appears in A and B
with opposite signs) is declared in ``[ties]`` as ``name = { entry = coefficient, ... }``. A tie
may also act on the output equation: the entry ``"<output>:<state or input>"`` adds to C or D
(an output scale factor ``k_q = { "q:q" = 1.0 }``, a drift on a time pseudo-input ``"q:t"``).

Outputs are states, state derivatives (``q_dot``) or linear combinations declared in
``[output_defs]`` as ``name = { term = coefficient, ... }`` whose terms are states, state
derivatives and inputs (for example a specific force ``a_x = { u_dot = 1.0, theta = 9.81 }``).

What flight-test models need besides the matrices (every table optional)::

    [process_noise]        # F of dx/dt = A x + B u + F w (w unit white noise): start values per state
    u = 0.05               # (default: the velocity equations u, v, w, the states turbulence drives)
    [initial_state]        # known initial states, held at these values in every run (x0 fixed)
    p = 0.0
    [zero_shifts]          # per output: a number (estimated, its start value), false (none) or
    a_y = 0.0              # { value = ..., fixed = true } (held at a known value); unlisted outputs
    p = false              # get an estimated zero shift starting at 0, as before
    [biases]               # constant state-equation biases, free parameters <equation>_one on the
    L = 0.0                # constant pseudo-input ``one`` (as refine writes them)
    input_hold = "linear"  # (top level) inputs between samples: "held" (default) or "linear"
    [turbulence]           # gusts the filter-error method models (identify.model.turbulence):
    states = ["u", "w"]    # the velocities they act on (alpha/beta form: w -> alpha, v -> beta)
    corner = 0.7           # optional, rad/s, held (a number or {u = ..}); default: estimated
    scale_length = 300.0   # optional: corner = airspeed / scale_length (Dryden), with
    airspeed = 53.6        # m/s (else the runs' "airspeed" metadata)
    [prior]                # a priori weighting: parameter = std around its [free] value, or
    M_q = 0.4              # { value = ..., std = ... } (see identify.model.prior)

A run's metadata ``input_hold`` overrides the profile's for that run (filter-error method).
"""
from __future__ import annotations

import json
import math
import re
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

from ..errors import ProfileError, read_text
from .prior_table import parse_prior, prior_toml_lines

EQUATION_OF_STATE = {"u": "X", "v": "Y", "w": "Z", "p": "L", "q": "M", "r": "N"}
DOT = "_dot"
_KNOWN_KEYS = {"name", "description", "states", "inputs", "outputs", "output_defs", "free",
               "fixed", "ties", "meta", "limits", "process_noise", "initial_state", "zero_shifts", "biases",
               "input_hold", "turbulence", "prior"}
VELOCITY_STATES = ("u", "v", "w")  # the equations turbulence drives: the default process noise
INPUT_HOLDS = ("held", "linear")
BIAS_INPUT = "one"  # the constant pseudo-input of state-equation biases (refine's name too)


@dataclass(frozen=True)
class Entry:
    """Position of a named entry: ``matrix`` is ``"A"``, ``"B"`` or, for output-equation
    entries ``<output>:<term>``, ``"C"`` (a state term) or ``"D"`` (an input term)."""

    matrix: str
    row: int
    col: int


@dataclass(frozen=True)
class Profile:
    """A parsed, validated a priori model. Build with :func:`load_profile` or :func:`parse_profile`."""

    name: str
    states: dict[str, str]
    inputs: dict[str, str]
    outputs: tuple[str, ...]
    free: dict[str, float]
    fixed: dict[str, float] = field(default_factory=dict)
    ties: dict[str, dict[str, float]] = field(default_factory=dict)
    output_defs: dict[str, dict[str, float]] = field(default_factory=dict)
    description: str = ""
    meta: dict[str, object] = field(default_factory=dict)
    source: str = "<profile>"
    # largest |perturbation| each output may reach in a test manoeuvre, in the output's own units
    # (signal design keeps every output's peak response within it)
    limits: dict[str, float] = field(default_factory=dict)
    # F start values {state: F} (empty: the default, velocity states); x0 held {state: value};
    # {output: {"value": start or held value, "estimate": bool}}; inputs between samples
    process_noise: dict[str, float] = field(default_factory=dict)
    initial_state: dict[str, float] = field(default_factory=dict)
    zero_shifts: dict[str, dict] = field(default_factory=dict)
    input_hold: str = "held"
    # gusts declared for the filter-error method ({} none): states, corner, scale_length, airspeed,
    # corner_start, intensity, kinematic (:func:`parse_turbulence`; identify.model.turbulence)
    turbulence: dict = field(default_factory=dict)
    # a priori weighting {free parameter: {"value": centre, "std": std}} (identify.model.prior)
    prior: dict[str, dict[str, float]] = field(default_factory=dict)

    def __post_init__(self):
        _validate(self)

    # -- names --------------------------------------------------------------------------------
    @property
    def state_names(self) -> list[str]:
        return list(self.states)

    @property
    def input_names(self) -> list[str]:
        return list(self.inputs)

    @property
    def free_names(self) -> list[str]:
        return list(self.free)

    def equation(self, state: str) -> str:
        """Equation name of a state: ``q`` -> ``M``, ``theta`` -> ``theta``."""
        return EQUATION_OF_STATE.get(state, state)

    def parse_entry(self, name: str) -> Entry:
        """Locate ``<equation>_<state|input>`` in A or B, or ``<output>:<state|input>`` in C or D;
        raise ProfileError unless unique."""
        if ":" in name:
            return _parse_output_entry(name, self)
        return _parse_entry(name, self.state_names, self.input_names, self.source)

    def entry_name(self, matrix: str, row: int, col: int) -> str:
        """Inverse of :meth:`parse_entry`."""
        cols = self.state_names if matrix in "AC" else self.input_names
        if matrix in "CD":
            return f"{self.outputs[row]}:{cols[col]}"
        return f"{self.equation(self.state_names[row])}_{cols[col]}"

    def parameter_entries(self, name: str) -> list[tuple[Entry, float]]:
        """Entries a parameter acts on, with their coefficients."""
        if name in self.ties:
            return [(self.parse_entry(e), float(c)) for e, c in self.ties[name].items()]
        return [(self.parse_entry(name), 1.0)]

    def output_terms(self, output: str) -> dict[str, float]:
        """Linear combination forming an output, as ``{term: coefficient}``."""
        if output in self.output_defs:
            return dict(self.output_defs[output])
        return {output: 1.0}

    def process_noise_states(self) -> dict[str, float | None]:
        """``{state: F start value}`` of the states with process noise: the ``[process_noise]``
        table, else the velocity states (start value None: chosen from the data)."""
        if self.process_noise:
            return dict(self.process_noise)
        return {s: None for s in VELOCITY_STATES if s in self.states}

    def zero_shift(self, output: str) -> tuple[float, bool]:
        """``(start or held value, estimated)`` of an output's zero shift."""
        spec = self.zero_shifts.get(output, {"value": 0.0, "estimate": True})
        return float(spec["value"]), bool(spec["estimate"])

    @property
    def channels(self) -> list[str]:
        """Channels a run must hold for this profile: inputs, then outputs."""
        return self.input_names + [y for y in self.outputs if y not in self.inputs]

    @property
    def parameters(self) -> dict[str, float]:
        return {**self.fixed, **self.free}

    # -- derived profiles ---------------------------------------------------------------------
    def with_values(self, values: dict[str, float], name: str | None = None) -> "Profile":
        """Copy with new values for free (or fixed) parameters, keeping the structure."""
        unknown = set(values) - set(self.free) - set(self.fixed)
        if unknown:
            raise ProfileError(f"{self.source}: unknown parameter(s) {', '.join(sorted(unknown))}")
        free = {k: float(values.get(k, v)) for k, v in self.free.items()}
        fixed = {k: float(values.get(k, v)) for k, v in self.fixed.items()}
        return replace(self, free=free, fixed=fixed, name=name or self.name)

    # -- serialisation ------------------------------------------------------------------------
    def to_toml(self) -> str:
        """TOML text that :func:`parse_profile` reads back to an equal profile."""
        lines = [f"name = {_toml_str(self.name)}"]
        if self.description:
            lines.append(f"description = {_toml_str(self.description)}")
        lines.append(f"states = {_inline(self.states)}")
        lines.append(f"inputs = {_inline(self.inputs)}")
        lines.append("outputs = [" + ", ".join(_toml_str(y) for y in self.outputs) + "]")
        if self.input_hold != "held":  # a top-level key: before the first table
            lines.append(f"input_hold = {_toml_str(self.input_hold)}")
        for table in ("output_defs", "ties"):
            rows = getattr(self, table)
            if rows:
                lines += ["", f"[{table}]"] + [f"{_key(k)} = {_inline(v)}" for k, v in rows.items()]
        if self.zero_shifts:
            lines += ["", "[zero_shifts]"] + [
                f"{_key(k)} = {_inline({'value': v['value'], 'fixed': not v['estimate']})}"
                for k, v in self.zero_shifts.items()]
        for table in ("free", "fixed", "limits", "process_noise", "initial_state", "turbulence", "meta"):
            rows = getattr(self, table)
            if rows:
                lines += ["", f"[{table}]"] + [f"{_key(k)} = {_toml_value(v)}" for k, v in rows.items()]
        lines += prior_toml_lines({k: v for k, v in self.prior.items() if k in self.free})
        return "\n".join(lines) + "\n"

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.write_text(self.to_toml())
        return path


# -- loading ----------------------------------------------------------------------------------
def output_units(profile: Profile) -> dict[str, str]:
    """Unit of every output, the one rule for plots, noise levels and reports: a state's or an
    input's own unit; ``<unit>/s`` for a state derivative (``rad/s/s`` is written ``rad/s^2``); for
    an output defined in ``[output_defs]`` the unit of its first state-derivative term, else of its
    first state term (inputs do not set it); ``""`` when none is known."""
    def unit(term: str) -> str:
        if term in profile.states:
            return profile.states[term]
        if term in profile.inputs:
            return profile.inputs[term]
        if term.endswith(DOT) and term[:-len(DOT)] in profile.states:
            base = profile.states[term[:-len(DOT)]]
            return base[:-2] + "/s^2" if base.endswith("/s") else base + "/s"
        return ""

    units = {}
    for y in profile.outputs:
        if y not in profile.output_defs:
            units[y] = unit(y)
            continue
        terms = [t for t, c in profile.output_terms(y).items() if c and t not in profile.inputs]
        derivs = [t for t in terms if t.endswith(DOT) and t[:-len(DOT)] in profile.states]
        units[y] = unit((derivs or terms or [y])[0])
    return units


def bundled_profiles_dir() -> Path:
    """Folder of the profiles shipped with pseudostep.

    ``profiles/`` sits beside the ``identify`` package both in the source tree and in an
    installation (it is shipped as package data of its own top-level folder).
    """
    return Path(__file__).resolve().parents[2] / "profiles"


def resolve_profile_path(spec: str | Path) -> Path:
    """A path as given, else a bundled profile by file name with or without ``.toml``."""
    path = Path(spec)
    if path.exists():
        return path
    for candidate in (bundled_profiles_dir() / path.name, bundled_profiles_dir() / f"{path.name}.toml"):
        if candidate.exists():
            return candidate
    available = ", ".join(sorted(p.stem for p in bundled_profiles_dir().glob("*.toml")))
    raise ProfileError(f"{spec}: no such profile file (bundled profiles: {available})")


def load_profile(spec: str | Path) -> Profile:
    """Read a profile from a path or a bundled profile's name (``s61_hover_8state``)."""
    path = resolve_profile_path(spec)
    return parse_profile(read_text(path, ProfileError, "profile"), source=str(path))


def parse_profile(text: str, source: str = "<profile>") -> Profile:
    """Parse profile TOML text; every problem raises one ProfileError naming ``source``."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ProfileError(f"{source}: not valid TOML ({exc})") from None
    unknown = set(data) - _KNOWN_KEYS
    if unknown:
        raise ProfileError(f"{source}: unknown key(s) {', '.join(sorted(unknown))}")
    for key in ("name", "states", "inputs", "outputs"):
        if key not in data:
            raise ProfileError(f"{source}: missing '{key}'")
    data = _with_coefficient_ties(_with_biases(data, source), source)
    free = _numbers(data.get("free", {}), "free", source)
    return Profile(
        name=_require(str, data["name"], "name", source),
        description=_require(str, data.get("description", ""), "description", source),
        states=_units(data["states"], "states", source),
        inputs=_units(data["inputs"], "inputs", source),
        outputs=tuple(_require(str, y, "outputs", source) for y in _require(list, data["outputs"], "outputs", source)),
        free=free,
        fixed=_numbers(data.get("fixed", {}), "fixed", source),
        ties={k: _numbers(v, f"ties.{k}", source) for k, v in _require(dict, data.get("ties", {}), "ties", source).items()},
        output_defs={k: _numbers(v, f"output_defs.{k}", source)
                     for k, v in _require(dict, data.get("output_defs", {}), "output_defs", source).items()},
        meta=_require(dict, data.get("meta", {}), "meta", source),
        source=source,
        limits=_numbers(data.get("limits", {}), "limits", source),
        process_noise=_numbers(data.get("process_noise", {}), "process_noise", source),
        initial_state=_numbers(data.get("initial_state", {}), "initial_state", source),
        zero_shifts={k: _zero_shift(k, v, source)
                     for k, v in _require(dict, data.get("zero_shifts", {}), "zero_shifts", source).items()},
        input_hold=_require(str, data.get("input_hold", "held"), "input_hold", source),
        turbulence=parse_turbulence(data.get("turbulence", {}), data["states"], source),
        prior=parse_prior(data.get("prior", {}), free, source),
    )


TURBULENCE_KEYS = ("states", "corner", "scale_length", "airspeed", "corner_start", "intensity", "kinematic",
                   "likelihood")
TURBULENCE_LIKELIHOODS = ("profile", "diffuse")  # x0 and zero shifts estimated with the rest, or integrated out
FLOW_ANGLES = {"w": "alpha", "v": "beta", "u": "V"}  # a profile in alpha/beta form: the state a gust moves


def gust_velocity(name: str, states) -> str:
    """The state a gust on ``name`` acts on: the state itself, or in a profile written in flow
    angles (no ``w``/``v``/``u`` state) ``alpha`` for w, ``beta`` for v, ``V`` for u."""
    if name not in states and FLOW_ANGLES.get(name) in states:
        return FLOW_ANGLES[name]
    return name


def parse_turbulence(table, states, source: str) -> dict:
    """The ``[turbulence]`` table, normalised: ``states`` (list, flow-angle form mapped),
    per-state ``corner`` (held, rad/s), ``corner_start``, ``intensity`` (F starts), a positive
    ``scale_length`` (m) and ``airspeed`` (m/s), ``kinematic`` entries, ``likelihood`` ("profile",
    the default, or "diffuse": :mod:`identify.model.turbulence`); {} when not declared."""
    table = _require(dict, table, "turbulence", source)
    if not table:
        return {}
    unknown = set(table) - set(TURBULENCE_KEYS)
    if unknown:
        raise ProfileError(f"{source}: [turbulence] unknown key(s) {', '.join(sorted(unknown))} "
                           f"(known: {', '.join(TURBULENCE_KEYS)})")
    listed = table.get("states")
    if isinstance(listed, str):
        listed = [s.strip() for s in listed.split(",") if s.strip()]
    if not isinstance(listed, list) or not listed or not all(isinstance(s, str) for s in listed):
        raise ProfileError(f"{source}: [turbulence] states must list the velocity states gusts act on "
                           f"(for example states = [\"u\", \"w\"])")
    gusts = [gust_velocity(s, states) for s in listed]
    bad = [s for s, g in zip(listed, gusts) if g not in states]
    if bad or len(set(gusts)) != len(gusts):
        raise ProfileError(f"{source}: [turbulence] states: {', '.join(bad) or 'a state listed twice'}: "
                           f"expected distinct states of the profile ({', '.join(states)})")
    out = {"states": gusts}
    for key in ("corner", "corner_start", "intensity"):
        if key in table:
            value = table[key]
            per = dict.fromkeys(gusts, value) if not isinstance(value, dict) else \
                {gust_velocity(k, states): v for k, v in value.items()}
            per = _numbers(per, f"turbulence.{key}", source)
            if set(per) - set(gusts) or any(v <= 0 for v in per.values()):
                raise ProfileError(f"{source}: [turbulence] {key}: positive values for the listed states "
                                   f"({', '.join(gusts)}), got {value!r}")
            out[key] = per
    for key in ("scale_length", "airspeed"):
        if key in table:
            value = _numbers({key: table[key]}, "turbulence", source)[key]
            if value <= 0:
                raise ProfileError(f"{source}: [turbulence] {key} = {value:g} must be positive")
            out[key] = value
    if "corner" in out and "scale_length" in out:
        raise ProfileError(f"{source}: [turbulence] corner and scale_length both given: one sets the other")
    if "kinematic" in table:
        kin = table["kinematic"]
        if not isinstance(kin, list) or not all(isinstance(k, str) for k in kin):
            raise ProfileError(f"{source}: [turbulence] kinematic must list entries (for example [\"h_w\"])")
        out["kinematic"] = list(kin)
    if "likelihood" in table:
        if table["likelihood"] not in TURBULENCE_LIKELIHOODS:
            raise ProfileError(f"{source}: [turbulence] likelihood must be one of {', '.join(TURBULENCE_LIKELIHOODS)}, "
                               f"got {table['likelihood']!r}")
        out["likelihood"] = table["likelihood"]
    return out


def _with_biases(data: dict, source: str) -> dict:
    """``[biases] L = 0.0`` written out as what it is: a free ``L_one`` on the constant
    pseudo-input ``one`` (so every estimator and refine see an ordinary parameter)."""
    biases = _numbers(data.get("biases", {}), "biases", source)
    if not biases:
        return data
    data = dict(data)
    data["inputs"] = {**_require(dict, data.get("inputs", {}), "inputs", source), BIAS_INPUT: "1"}
    meta = dict(_require(dict, data.get("meta", {}), "meta", source))
    meta["pseudo_inputs"] = {**meta.get("pseudo_inputs", {}), BIAS_INPUT: {"constant": 1.0}}
    data["meta"] = meta
    data["free"] = {**data.get("free", {}), **{f"{eq}_{BIAS_INPUT}": v for eq, v in biases.items()}}
    return data


def _with_coefficient_ties(data: dict, source: str) -> dict:
    """A coefficient-form profile's coefficient derivatives (``C_m_alpha``) as ties onto their
    dimensional entries at the reference condition (:mod:`identify.model.coefficients`)."""
    from . import coefficients

    table = coefficients.spec(_require(dict, data.get("meta", {}), "meta", source), source)
    if table is None:
        return data
    names = list(data.get("free", {})) + list(data.get("fixed", {}))
    existing = _require(dict, data.get("ties", {}), "ties", source)
    try:
        made = coefficients.ties(names, data["states"], data["inputs"], table, existing)
    except (KeyError, TypeError, ValueError) as exc:
        raise ProfileError(f"{source}: meta.coefficients: {exc}") from None
    return {**data, "ties": {**made, **existing}}


def _zero_shift(output: str, spec, source: str) -> dict:
    if spec is False:
        return {"value": 0.0, "estimate": False}
    if isinstance(spec, (int, float)) and not isinstance(spec, bool):
        return {"value": float(spec), "estimate": True}
    if isinstance(spec, dict) and set(spec) <= {"value", "fixed"} and "value" in spec:
        value = _numbers({"value": spec["value"]}, f"zero_shifts.{output}", source)["value"]
        return {"value": value, "estimate": not bool(spec.get("fixed", False))}
    raise ProfileError(f"{source}: [zero_shifts] {output} = {spec!r}: expected a start value, false, "
                       f"or {{ value = ..., fixed = true }}")


def _require(kind, value, where, source):
    if not isinstance(value, kind):
        raise ProfileError(f"{source}: '{where}' must be a {kind.__name__}, got {value!r}")
    return value


def _units(table, where, source) -> dict[str, str]:
    table = _require(dict, table, where, source)
    for name, unit in table.items():
        if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", name):
            raise ProfileError(f"{source}: {where} name '{name}' is not an identifier")
        _require(str, unit, f"{where}.{name}", source)
    return dict(table)


def _numbers(table, where, source) -> dict[str, float]:
    table = _require(dict, table, where, source)
    out = {}
    for name, value in table.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ProfileError(f"{source}: [{where}] {name} = {value!r} is not a number")
        if not math.isfinite(value):
            raise ProfileError(f"{source}: [{where}] {name} = {value!r} is not finite")
        out[name] = float(value)
    return out


# -- validation -------------------------------------------------------------------------------
def _parse_entry(name: str, states: list[str], inputs: list[str], source: str) -> Entry:
    equations = {EQUATION_OF_STATE.get(s, s): i for i, s in enumerate(states)}
    found = []
    for cut in (m.start() for m in re.finditer("_", name)):
        eq, var = name[:cut], name[cut + 1:]
        if eq in equations and var in states:
            found.append(Entry("A", equations[eq], states.index(var)))
        elif eq in equations and var in inputs:
            found.append(Entry("B", equations[eq], inputs.index(var)))
    if len(found) == 1:
        return found[0]
    if found:
        raise ProfileError(f"{source}: derivative name '{name}' is ambiguous")
    raise ProfileError(f"{source}: '{name}' names no derivative: expected <equation>_<state or input> "
                       f"with equations {', '.join(equations)}")


def _parse_output_entry(name: str, p: Profile) -> Entry:
    output, _, term = name.partition(":")
    if output not in p.outputs:
        raise ProfileError(f"{p.source}: output entry '{name}': '{output}' is not an output")
    if term in p.states:
        return Entry("C", p.outputs.index(output), p.state_names.index(term))
    if term in p.inputs:
        return Entry("D", p.outputs.index(output), p.input_names.index(term))
    raise ProfileError(f"{p.source}: output entry '{name}': '{term}' is not a state or input")


def _validate(p: Profile) -> None:
    src = p.source
    if not p.states:
        raise ProfileError(f"{src}: no states declared")
    clash = set(p.states) & set(p.inputs)
    if clash:
        raise ProfileError(f"{src}: name(s) {', '.join(sorted(clash))} declared as both state and input")
    both = set(p.free) & set(p.fixed)
    if both:
        raise ProfileError(f"{src}: parameter(s) {', '.join(sorted(both))} declared both free and fixed")
    for tie in p.ties:
        if tie not in p.free and tie not in p.fixed:
            raise ProfileError(f"{src}: tied parameter '{tie}' is neither free nor fixed")
    owner: dict[Entry, str] = {}
    for name in list(p.free) + list(p.fixed):
        for entry, _ in p.parameter_entries(name):
            if entry in owner:
                raise ProfileError(f"{src}: derivative '{p.entry_name(*_astuple(entry))}' set by both "
                                   f"'{owner[entry]}' and '{name}'")
            owner[entry] = name
    if len(set(p.outputs)) != len(p.outputs):
        raise ProfileError(f"{src}: duplicate output names")
    terms_ok = set(p.states) | {s + DOT for s in p.states} | set(p.inputs)
    for y in p.outputs:
        for term in p.output_terms(y):
            if term not in terms_ok:
                what = f"output '{y}'" if y in p.output_defs else "output"
                raise ProfileError(f"{src}: {what} term '{term}' is not a state, state derivative or input")
    for table in ("process_noise", "initial_state"):
        for s in getattr(p, table):
            if s not in p.states:
                raise ProfileError(f"{src}: [{table}] {s}: not a state (states: {', '.join(p.states)})")
    if p.turbulence:  # a profile built in code: the same checks as the table's
        parse_turbulence(p.turbulence, p.states, src)
    for y in p.zero_shifts:
        if y not in p.outputs:
            raise ProfileError(f"{src}: [zero_shifts] {y}: not an output (outputs: {', '.join(p.outputs)})")
    if p.input_hold not in INPUT_HOLDS:
        raise ProfileError(f"{src}: input_hold = {p.input_hold!r}: expected one of {', '.join(INPUT_HOLDS)}")
    for y, limit in p.limits.items():
        if y not in p.outputs:
            raise ProfileError(f"{src}: [limits] {y}: not an output (outputs: {', '.join(p.outputs)})")
        if not limit > 0:
            raise ProfileError(f"{src}: [limits] {y} = {limit:g} must be positive")


def _astuple(entry: Entry):
    return entry.matrix, entry.row, entry.col


# -- TOML writing (tomllib only reads) --------------------------------------------------------
def _toml_str(s: str) -> str:
    return json.dumps(s, ensure_ascii=False)


def _key(k: str) -> str:
    return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else _toml_str(k)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(float(v)) if isinstance(v, float) else str(v)
    if isinstance(v, str):
        return _toml_str(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return _inline(v)
    raise TypeError(f"cannot write {v!r} to TOML")


def _inline(d: dict) -> str:
    return "{ " + ", ".join(f"{_key(k)} = {_toml_value(v)}" for k, v in d.items()) + " }"
