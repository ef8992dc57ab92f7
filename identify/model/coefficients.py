"""Coefficient form: equations written in non-dimensional aerodynamic coefficients.

Fixed-wing data are modelled in the textbook's coefficients (``C_L``, ``C_m``, ...) rather than in
dimensional derivatives; a profile says so in ``[meta.coefficients]``::

    [meta.coefficients]
    airspeed = "V"          # the airspeed channel (m/s), for the dynamic pressure of every sample
    V0 = 53.6               # m/s: the reference airspeed of the linear model
    density = 1.225         # kg/m^3
    area = 16.7             # S, m^2
    chord = 1.74            # c, m (pitching moment, q c / 2V)
    span = 10.2             # b, m (rolling and yawing moments, p b / 2V, r b / 2V)
    mass = 1270.0           # kg
    inertia = { M = 4070.0 }                    # kg m^2 per moment equation
    equations = { Z = "C_L", M = "C_m" }       # an equation's coefficient
    accelerometers = { X = "a_x", Z = "a_z" }  # body-axis specific forces (m/s^2), optional

A free or fixed parameter ``<coefficient>_<variable>`` (``C_m_alpha``, ``C_L_delta_e``,
``C_m_alpha_sq``) is a coefficient derivative. Its variable is ``alpha`` (w / V), ``beta`` (v / V),
a rate made non-dimensional (``q c / 2V``; ``p b / 2V``, ``r b / 2V``), ``u`` (u / V0), an input or a
pseudo-input (as recorded: ``alpha_sq`` built from an ``alpha`` channel). The linear model sees it
as a tie onto the dimensional entry, at the reference dynamic pressure ``qbar0 = rho V0^2 / 2``:
``C_m_alpha`` acts on ``M_w`` with ``qbar0 S c / (I_M V0)``. Lift and drag act against the body
axes' Z and X (``C_L`` on Z with sign -1: small-angle, the linear model's approximation).

Equation error uses the coefficients themselves, sample by sample (:func:`measured`,
:func:`regressor`): the dynamic pressure from the airspeed channel, moments from the rates'
derivatives (``C_m = I_M q_dot / (qbar S c)``, cross-inertia terms neglected), forces from the
accelerometers where given (``C_Z = m a_z / (qbar S)``; ``C_L = -C_Z cos(alpha) + C_X sin(alpha)``
with thrust left in ``C_X``), else from the state derivative less the profile's known part.
"""
from __future__ import annotations

import numpy as np

from ..errors import ProfileError

# coefficient -> (equation, sign): the force or moment it measures along the body axes
COEFFICIENTS = {"C_X": ("X", 1.0), "C_Y": ("Y", 1.0), "C_Z": ("Z", 1.0), "C_L": ("Z", -1.0), "C_D": ("X", -1.0),
                "C_l": ("L", 1.0), "C_m": ("M", 1.0), "C_n": ("N", 1.0)}
MOMENTS = {"L": "span", "M": "chord", "N": "span"}
RATE_LENGTH = {"p": "span", "q": "chord", "r": "span"}
ANGLES = {"alpha": "w", "beta": "v"}
_NEEDED = ("V0", "density", "area", "mass", "equations")


def spec(meta: dict, source: str = "<profile>") -> dict | None:
    """The validated ``meta.coefficients`` table, or None for a dimensional profile."""
    table = meta.get("coefficients")
    if table is None:
        return None
    if not isinstance(table, dict):
        raise ProfileError(f"{source}: meta.coefficients must be a table (see identify.model.coefficients)")
    missing = [k for k in _NEEDED if k not in table]
    if missing:
        raise ProfileError(f"{source}: meta.coefficients lacks {', '.join(missing)}")
    eqs = dict(table["equations"])
    for eq, coef in eqs.items():
        if coef not in COEFFICIENTS or COEFFICIENTS[coef][0] != eq:
            raise ProfileError(f"{source}: meta.coefficients.equations: {eq} = {coef!r} (known: "
                               + ", ".join(f"{e} = {c}" for c, (e, _) in COEFFICIENTS.items()) + ")")
        if eq in MOMENTS and (MOMENTS[eq] not in table or eq not in dict(table.get("inertia", {}))):
            raise ProfileError(f"{source}: meta.coefficients: the {coef} equation needs '{MOMENTS[eq]}' and "
                               f"inertia.{eq}")
    return table


def split_name(name: str, table: dict) -> tuple[str, str] | None:
    """``C_m_alpha`` -> (``C_m``, ``alpha``) for a coefficient the profile declares, else None."""
    for coef in sorted(set(dict(table["equations"]).values()), key=len, reverse=True):
        if name.startswith(coef + "_") and len(name) > len(coef) + 1:
            return coef, name[len(coef) + 1:]
    return None


def column(variable: str, states, inputs) -> str:
    """The state or input of the linear model a coefficient variable stands for."""
    if variable in ANGLES and variable not in states and variable not in inputs:
        return ANGLES[variable]
    if variable in states or variable in inputs:
        return variable
    raise ProfileError(f"coefficient variable '{variable}' is no state, input, alpha or beta")


def reference_factor(coef: str, variable: str, table: dict, states, inputs) -> float:
    """Dimensional entry per unit coefficient derivative at the reference condition."""
    eq, sign = COEFFICIENTS[coef]
    V0, rho, S = float(table["V0"]), float(table["density"]), float(table["area"])
    qbar0 = 0.5 * rho * V0 ** 2
    scale = qbar0 * S / float(table["mass"]) if eq not in MOMENTS else \
        qbar0 * S * float(table[MOMENTS[eq]]) / float(dict(table["inertia"])[eq])
    col = column(variable, states, inputs)
    if col in ("u", "v", "w") and col in states:
        scale /= V0
    elif col in RATE_LENGTH and col in states:
        scale *= float(table[RATE_LENGTH[col]]) / (2 * V0)
    return sign * scale


def ties(names, states, inputs, table: dict, existing=()) -> dict[str, dict[str, float]]:
    """``{parameter: {entry: factor}}`` for every coefficient parameter of ``names`` not already tied."""
    out = {}
    for name in names:
        parts = split_name(name, table)
        if parts is None or name in existing:
            continue
        coef, variable = parts
        eq = COEFFICIENTS[coef][0]
        out[name] = {f"{eq}_{column(variable, states, inputs)}": reference_factor(coef, variable, table, states, inputs)}
    return out


# -- equation error in coefficients ---------------------------------------------------------------
def dynamic_pressure(run, table: dict) -> np.ndarray:
    name = table.get("airspeed", "V")
    V = run[name] if name in run.channels else np.full(len(run), float(table["V0"]))
    return 0.5 * float(table["density"]) * V ** 2


def airspeed(run, table: dict) -> np.ndarray:
    name = table.get("airspeed", "V")
    return run[name] if name in run.channels else np.full(len(run), float(table["V0"]))


def angle(run, variable: str, table: dict) -> np.ndarray:
    """alpha or beta: the channel if recorded, else w / V or v / V."""
    if variable in run.channels:
        return run[variable]
    return run[ANGLES[variable]] / airspeed(run, table)


def regressor(run, variable: str, table: dict, states) -> np.ndarray:
    """The non-dimensional regressor of a coefficient derivative on one run."""
    if variable in ANGLES:
        return angle(run, variable, table)
    if variable in RATE_LENGTH and variable in states:
        return run[variable] * float(table[RATE_LENGTH[variable]]) / (2 * airspeed(run, table))
    if variable in ("u", "v", "w") and variable in states:
        # per unit reference airspeed, as the tie's factor: u / V would be cos(alpha), a function of alpha
        return run[variable] / float(table["V0"])
    return run[variable]


def measured(run, eq: str, table: dict, aero: np.ndarray, all_aero: dict[str, np.ndarray]) -> np.ndarray:
    """The coefficient of equation ``eq`` on one run. ``aero``: that equation's state derivative
    less the profile's known part (per unit mass or inertia); ``all_aero`` the same of the
    other equations (lift and drag combine X and Z)."""
    coef = dict(table["equations"])[eq]
    qS = dynamic_pressure(run, table) * float(table["area"])
    if eq in MOMENTS:
        return float(dict(table["inertia"])[eq]) * aero / (qS * float(table[MOMENTS[eq]]))
    m = float(table["mass"])
    acc = dict(table.get("accelerometers", {}))

    def body(axis):
        if acc.get(axis) in run.channels:
            return m * run[acc[axis]] / qS
        if axis not in all_aero:
            raise ProfileError(f"coefficient {coef} needs the {axis} force: an accelerometer "
                               f"(meta.coefficients.accelerometers.{axis}) or the {axis} equation")
        return m * all_aero[axis] / qS

    if coef in ("C_X", "C_Y", "C_Z"):
        return body(eq)
    a = angle(run, "alpha", table)
    cx, cz = body("X"), body("Z")
    if coef == "C_L":
        return -cz * np.cos(a) + cx * np.sin(a)
    return -cx * np.cos(a) - cz * np.sin(a)  # C_D


def reference_dynamic_pressure(table: dict) -> float:
    return 0.5 * float(table["density"]) * float(table["V0"]) ** 2


__all__ = ["COEFFICIENTS", "spec", "split_name", "column", "reference_factor", "ties", "dynamic_pressure",
           "airspeed", "angle", "regressor", "measured", "reference_dynamic_pressure"]
