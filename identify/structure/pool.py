"""The candidate pool of structure determination: the terms a model might hold beyond its profile.

* every *undeclared* A or B entry of a dynamic equation (an equation with a free parameter; the
  kinematic ones, ``theta_dot = q``, are known): ``M_p`` = the pitch moment due to roll rate;
* with ``nonlinear`` (names of measured states and inputs): in every dynamic equation, for each
  named ``x`` its square ``x_sq``, ``x|x|`` (``x_absx``), the linear splines
  ``max(x - k, 0)`` at the ``knots`` given for it (``x_k1``, ``x_k2``, ...: a slope that changes
  at ``k``, as a lift curve near stall) and the products ``x_x_y`` of every pair of named channels.

Nonlinear terms enter the model as pseudo-inputs (:mod:`identify.model.pseudo_inputs`) with a B
entry ``<equation>_<term>``, so the final profile rebuilds them from any run. Every candidate is
added to one *extended* profile as a free parameter at zero; the regression then chooses.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from itertools import combinations

from ..errors import ProfileError
from ..model import coefficients as cf
from ..model import pseudo_inputs as pi
from ..model.profile import Profile


@dataclass(frozen=True)
class Term:
    """A candidate parameter: its ``name`` (``M_p``, ``Z_w_sq``), ``kind`` (derivative, square,
    absolute, spline, product) and the pseudo-input it needs (``pseudo``: name and spec)."""

    name: str
    kind: str
    equation: str
    pseudo: tuple = ()


def dynamic_rows(p: Profile) -> list[int]:
    """Rows of A/B holding a free parameter: the equations whose structure is unknown."""
    rows = set()
    for name in p.free:
        for entry, _ in p.parameter_entries(name):
            if entry.matrix in "AB":
                rows.add(entry.row)
    return sorted(rows)


def controls(p: Profile) -> list[str]:
    pseudo = pi.specs(p)
    return [u for u in p.inputs if u not in pseudo]


def occupied(p: Profile) -> set[tuple[str, int, int]]:
    """(matrix, row, col) of every A/B entry a parameter already acts on."""
    out = set()
    for name in p.parameters:
        for entry, _ in p.parameter_entries(name):
            out.add((entry.matrix, entry.row, entry.col))
    return out


def derivative_terms(p: Profile, measured: set[str]) -> list[Term]:
    """Every undeclared A/B entry of a dynamic equation whose column is measured (in a
    coefficient equation: the coefficient derivative of every aerodynamic variable, ``C_m_u``)."""
    taken, out = occupied(p), []
    ctrl = controls(p)
    for i in dynamic_rows(p):
        eq = p.equation(p.state_names[i])
        for j, s in enumerate(p.state_names):
            if s in measured and ("A", i, j) not in taken:
                out.append(Term(_name(p, eq, "A", i, j), "derivative", eq))
        for j, u in enumerate(p.input_names):
            if u in ctrl and ("B", i, j) not in taken:
                out.append(Term(_name(p, eq, "B", i, j), "derivative", eq))
    return [t for t in out if t.name and (_coefficient(p, t.equation) or _unambiguous(p, t.name))]


def _coefficient(p: Profile, eq: str) -> str | None:
    """The coefficient an equation is written in (coefficient-form profiles), else None."""
    table = cf.spec(p.meta, p.source)
    return None if table is None else dict(table["equations"]).get(eq)


# states that are aerodynamic variables of a coefficient (attitudes are gravity's, not the air's)
_AERO = {"w": "alpha", "v": "beta", "u": "u", "p": "p", "q": "q", "r": "r"}


def _name(p: Profile, eq: str, matrix: str, i: int, j: int) -> str:
    coef = _coefficient(p, eq)
    if coef is None:
        return p.entry_name(matrix, i, j)
    if matrix == "B":
        return f"{coef}_{p.input_names[j]}"
    state = p.state_names[j]
    return f"{coef}_{_AERO[state]}" if state in _AERO else ""


def nonlinear_terms(p: Profile, names: list[str], knots: dict[str, list[float]] | None = None,
                    one_signed=()) -> list[Term]:
    """Squares, x|x|, splines at ``knots`` and pairwise products of the channels ``names`` in every
    dynamic equation (a term the profile already holds is skipped; x|x| of a channel in
    ``one_signed``, which never changes sign in the data, is +-x^2 there and left out)."""
    knots = knots or {}
    pseudo: list[tuple[str, str, dict]] = []
    for x in names:
        pseudo.append((f"{x}_sq", "square", pi.product([x, x])))
        if x not in one_signed:
            pseudo.append((f"{x}_abs{x}", "absolute", pi.product([x, x], [False, True])))
        pseudo += [(f"{x}_k{i + 1}", "spline", pi.spline(x, k)) for i, k in enumerate(sorted(knots.get(x, ())))]
    pseudo += [(f"{a}_x_{b}", "product", pi.product([a, b])) for a, b in combinations(names, 2)]
    out = []
    for i in dynamic_rows(p):
        eq = p.equation(p.state_names[i])
        for term, kind, spec in pseudo:
            name = f"{_coefficient(p, eq) or eq}_{term}"
            if name not in p.parameters:
                out.append(Term(name, kind, eq, (term, tuple((k, tuple(v) if isinstance(v, list) else v)
                                                             for k, v in sorted(spec.items())))))
    return out


def extended(p: Profile, terms: list[Term]) -> Profile:
    """``p`` with every term a free parameter at zero (and its pseudo-input declared)."""
    inputs, table = dict(p.inputs), dict(pi.specs(p))
    for t in terms:
        if t.pseudo:
            name, spec = t.pseudo
            if name not in inputs:
                inputs[name] = "nonlinear"
                table[name] = _spec(spec)
    meta = {**p.meta, **({"pseudo_inputs": table} if table else {})}
    q = replace(p, inputs=inputs, meta=meta)
    coefficients = cf.spec(p.meta, p.source)
    ties = {} if coefficients is None else cf.ties([t.name for t in terms], q.states, q.inputs, coefficients, p.ties)
    return replace(q, free={**p.free, **{t.name: 0.0 for t in terms}}, ties={**p.ties, **ties})


def with_terms(p: Profile, added: dict[str, float], pool: list[Term]) -> Profile:
    """``p`` with the pool's terms ``added`` free (their pseudo-inputs declared), at the values given."""
    chosen = [t for t in pool if t.name in added]
    q = extended(p, chosen)
    return q.with_values({k: float(v) for k, v in added.items()})


def _spec(items) -> dict:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in items}


def _unambiguous(p: Profile, name: str) -> bool:
    try:
        p.parse_entry(name)
    except ProfileError:
        return False
    return True


__all__ = ["Term", "dynamic_rows", "controls", "derivative_terms", "nonlinear_terms", "extended", "with_terms"]
