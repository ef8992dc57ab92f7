"""Linear models built from profiles: matrices, parameter derivatives, modes, reduction.

The model is linear in its free parameters ``theta`` (shape ``(p,)``)::

    A(theta) = A0 + sum_i theta_i dA[i]        dA: (p, n, n)
    B(theta) = B0 + sum_i theta_i dB[i]        dB: (p, n, m)
    y = C x + D u,  C = Cx + Cd A,  D = Du + Cd B

where ``Cd`` picks state derivatives for outputs such as ``q_dot`` or specific forces. Because the
dependence is linear, output sensitivities need only the constant tensors ``dA`` and ``dB``.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from ..errors import ProfileError
from .profile import DOT, Profile

if TYPE_CHECKING:
    import control


@dataclass(frozen=True)
class Mode:
    """One eigenvalue (or conjugate pair) of A: frequencies in rad/s, times in s."""

    eigenvalue: complex
    frequency: float  # natural frequency |lambda|
    damping: float  # -Re(lambda) / |lambda|
    period: float  # 2 pi / Im(lambda); inf for a real eigenvalue

    @property
    def oscillatory(self) -> bool:
        return np.isfinite(self.period)

    @property
    def stable(self) -> bool:
        return self.eigenvalue.real < 0

    @property
    def neutral(self) -> bool:
        """Real part zero to rounding (an integrator such as heading or position): neither
        converges nor diverges."""
        return abs(self.eigenvalue.real) <= NEUTRAL_TOLERANCE * max(1.0, abs(self.eigenvalue))

    @property
    def time_to_half_or_double(self) -> float:
        """ln 2 / |Re(lambda)|: time to half amplitude (stable) or to double (unstable)."""
        re = abs(self.eigenvalue.real)
        return np.log(2) / re if re > 0 else np.inf


def modes_of(A: np.ndarray) -> list[Mode]:
    """Modes of a square matrix, one per real eigenvalue or conjugate pair, slowest first."""
    out = []
    for lam in np.linalg.eigvals(A):
        if lam.imag < -1e-12 * max(1.0, abs(lam)):
            continue  # the conjugate of a pair already listed
        lam = complex(lam.real, max(lam.imag, 0.0))
        wn = abs(lam)
        zeta = -lam.real / wn if wn > 0 else 1.0
        period = 2 * np.pi / lam.imag if lam.imag > 1e-12 * max(1.0, wn) else np.inf
        out.append(Mode(lam, wn, zeta, period))
    return sorted(out, key=lambda m: (m.frequency, m.eigenvalue.imag))


NEUTRAL_TOLERANCE = 1e-9  # |Re(lambda)| / max(1, |lambda|) below which a mode counts as neutral


def format_modes(modes: list[Mode]) -> str:
    """Plain-text table of modes, the way an engineer reads them: ``-`` where a quantity does not
    exist (the period of a real eigenvalue, the time to half or double of a neutral mode)."""
    rows = [f"{'eigenvalue':>24}  {'omega [rad/s]':>13}  {'damping':>8}  {'period [s]':>10}  "
            f"{'t_half/t_double [s]':>19}  stability"]
    for m in modes:
        lam = m.eigenvalue
        ev = f"{lam.real:+.4f} {'±' if m.oscillatory else ' '} {abs(lam.imag):.4f}j" if m.oscillatory \
            else f"{lam.real:+.4f}"
        period = f"{m.period:10.2f}" if m.oscillatory else f"{'-':>10}"
        t2 = f"{'-':>19}" if m.neutral else f"{m.time_to_half_or_double:19.2f}"
        state = "neutral" if m.neutral else "stable" if m.stable else "UNSTABLE"
        damping = f"{m.damping:8.3f}" if m.frequency > 0 else f"{'-':>8}"  # undefined at the origin
        rows.append(f"{ev:>24}  {m.frequency:13.4f}  {damping}  {period}  {t2}  {state}")
    return "\n".join(rows)


class LinearModel:
    """The linear model of a profile at parameter values ``theta`` (a priori values by default).

    Attributes: ``profile``; ``names`` of the free parameters; ``theta`` (p,); ``A`` (n, n),
    ``B`` (n, m), ``C`` (ny, n), ``D`` (ny, m); ``dA`` (p, n, n), ``dB`` (p, n, m), ``dC``
    (p, ny, n), ``dD`` (p, ny, m) the constant derivatives of the matrices w.r.t. theta.
    """

    def __init__(self, profile: Profile, theta=None):
        self.profile = profile
        self.names = profile.free_names
        self.theta = np.array(list(profile.free.values()) if theta is None else theta, dtype=float)
        if self.theta.shape != (len(self.names),):
            raise ProfileError(f"{profile.source}: expected {len(self.names)} parameter values, "
                               f"got shape {self.theta.shape}")
        self._structure = _structure(profile)

    def with_theta(self, theta) -> "LinearModel":
        """Same structure, other free-parameter values."""
        return LinearModel(self.profile, theta)

    @property
    def n_states(self) -> int:
        return len(self.profile.states)

    @property
    def n_inputs(self) -> int:
        return len(self.profile.inputs)

    @property
    def n_outputs(self) -> int:
        return len(self.profile.outputs)

    @cached_property
    def A(self) -> np.ndarray:
        s = self._structure
        return s["A0"] + np.tensordot(self.theta, s["dA"], axes=1)

    @cached_property
    def B(self) -> np.ndarray:
        s = self._structure
        return s["B0"] + np.tensordot(self.theta, s["dB"], axes=1)

    @cached_property
    def C(self) -> np.ndarray:
        s = self._structure
        return s["Cx"] + np.tensordot(self.theta, s["dCx"], axes=1) + s["Cd"] @ self.A

    @cached_property
    def D(self) -> np.ndarray:
        s = self._structure
        return s["Du"] + np.tensordot(self.theta, s["dDu"], axes=1) + s["Cd"] @ self.B

    @property
    def A0(self) -> np.ndarray:
        """Fixed part of A (gravity, kinematics), (n, n)."""
        return self._structure["A0"]

    @property
    def B0(self) -> np.ndarray:
        """Fixed part of B, (n, m)."""
        return self._structure["B0"]

    @property
    def Cd(self) -> np.ndarray:
        """(ny, n) weights of the state derivatives in the outputs (``q_dot``, specific forces)."""
        return self._structure["Cd"]

    @property
    def dA(self) -> np.ndarray:
        return self._structure["dA"]

    @property
    def dB(self) -> np.ndarray:
        return self._structure["dB"]

    @property
    def dC(self) -> np.ndarray:
        return self._structure["dC"]

    @property
    def dD(self) -> np.ndarray:
        return self._structure["dD"]

    def to_ss(self) -> "control.StateSpace":
        """The model as a ``control.StateSpace`` with named states, inputs and outputs."""
        import control  # slow to import (~1 s) and needed only here: not at ``import identify``

        p = self.profile
        return control.ss(self.A, self.B, self.C, self.D, states=p.state_names,
                          inputs=p.input_names, outputs=list(p.outputs), name=p.name)

    def frequency_response(self, omega, inputs: list[str] | None = None,
                           outputs: list[str] | None = None) -> np.ndarray:
        """The continuous transfer matrix ``C (jwI - A)^-1 B + D`` at frequencies ``omega``.

        ``omega``: (nf,) rad/s (a scalar gives nf = 1). ``inputs`` / ``outputs``: names of the
        pairs wanted, default all of the profile's, in its order. Returns complex (nf, ny, nu)
        in output units per input unit (rad/s per rad for ``q/theta_s``), frequency first as in
        the measured :class:`~identify.estimators.frequency.FrequencyResponse` (python-control's
        ``frequency_response`` orders (ny, nu, nf)). Solved for all frequencies at once.
        """
        p = self.profile
        yi = [p.outputs.index(y) for y in (outputs or p.outputs)]
        ui = [p.input_names.index(u) for u in (inputs or p.input_names)]
        s = 1j * np.atleast_1d(np.asarray(omega, dtype=float))
        n = self.n_states
        X = np.linalg.solve(s[:, None, None] * np.eye(n) - self.A,
                            np.broadcast_to(self.B[:, ui], (len(s), n, len(ui))))
        return np.einsum("yn,fnu->fyu", self.C[yi], X) + self.D[np.ix_(yi, ui)]

    def modes(self) -> list[Mode]:
        return modes_of(self.A)

    @property
    def unstable(self) -> bool:
        return any(not m.stable for m in self.modes())

    def to_profile(self, name: str | None = None) -> Profile:
        """The profile with the current values as a priori values (the next a priori model)."""
        return self.profile.with_values(dict(zip(self.names, self.theta)), name=name)

    def parameters(self) -> dict[str, float]:
        return dict(zip(self.names, map(float, self.theta)))


def _structure(p: Profile) -> dict[str, np.ndarray]:
    """Constant matrices and parameter tensors of a profile (computed once per model)."""
    n, m, ny, npar = len(p.states), len(p.inputs), len(p.outputs), len(p.free)
    Cx, Cd, Du = _output_matrices(p)
    fixed = {"A": np.zeros((n, n)), "B": np.zeros((n, m)), "C": Cx, "D": Du}
    for name, value in p.fixed.items():
        _place(p, name, value, fixed)
    free = {"A": np.zeros((npar, n, n)), "B": np.zeros((npar, n, m)),
            "C": np.zeros((npar, ny, n)), "D": np.zeros((npar, ny, m))}
    for i, name in enumerate(p.free):
        _place(p, name, 1.0, {k: v[i] for k, v in free.items()})
    # C = Cx + Cd A: a parameter in A reaches derivative outputs through Cd
    return dict(A0=fixed["A"], B0=fixed["B"], dA=free["A"], dB=free["B"], Cx=fixed["C"], Cd=Cd, Du=fixed["D"],
                dCx=free["C"], dDu=free["D"],
                dC=free["C"] + np.einsum("yn,pnk->pyk", Cd, free["A"]),
                dD=free["D"] + np.einsum("yn,pnk->pyk", Cd, free["B"]))


def _place(p: Profile, name: str, value: float, matrices: dict[str, np.ndarray]) -> None:
    for entry, coeff in p.parameter_entries(name):
        matrices[entry.matrix][entry.row, entry.col] += coeff * value


def _output_matrices(p: Profile):
    states, inputs = p.state_names, p.input_names
    ny = len(p.outputs)
    Cx, Cd, Du = np.zeros((ny, len(states))), np.zeros((ny, len(states))), np.zeros((ny, len(inputs)))
    for i, y in enumerate(p.outputs):
        for term, coeff in p.output_terms(y).items():
            if term in states:
                Cx[i, states.index(term)] += coeff
            elif term in inputs:
                Du[i, inputs.index(term)] += coeff
            else:
                Cd[i, states.index(term[: -len(DOT)])] += coeff
    return Cx, Cd, Du


def residualize(model: LinearModel, fast: list[str], name: str | None = None,
                rtol: float = 1e-9) -> Profile:
    """Reduce a model by making ``fast`` states instantaneous (dx_fast/dt = 0).

    This is the paper's "mathematically reduced model": for the S 61, rotor tip-path-plane tilt is
    taken as instantaneous and the rotor's effect folds into the rigid-body derivatives::

        A_r = A_ss - A_sf A_ff^-1 A_fs,   B_r = B_s - A_sf A_ff^-1 B_f

    Entries changed by the reduction become free parameters; fixed entries the reduction leaves
    unchanged (gravity, kinematics) stay fixed. Outputs involving fast states are dropped.
    """
    p = model.profile
    missing = [s for s in fast if s not in p.states]
    if missing:
        raise ProfileError(f"{p.source}: cannot reduce: unknown state(s) {', '.join(missing)}")
    if len(set(fast)) != len(fast):
        raise ProfileError(f"{p.source}: cannot reduce: a state is listed twice in {', '.join(fast)}")
    if len(fast) >= model.n_states:
        raise ProfileError(f"{p.source}: cannot reduce: no state would be left")
    f_idx = [p.state_names.index(s) for s in fast]
    s_idx = [i for i in range(model.n_states) if i not in f_idx]
    A, B = model.A, model.B
    Aff = A[np.ix_(f_idx, f_idx)]
    try:
        gain = A[np.ix_(s_idx, f_idx)] @ np.linalg.inv(Aff)
    except np.linalg.LinAlgError:
        raise ProfileError(f"{p.source}: cannot reduce: the fast states' matrix is singular") from None
    Ar = A[np.ix_(s_idx, s_idx)] - gain @ A[np.ix_(f_idx, s_idx)]
    Br = B[s_idx] - gain @ B[f_idx]
    corr_A, corr_B = Ar - A[np.ix_(s_idx, s_idx)], Br - B[s_idx]
    slow = [p.state_names[i] for i in s_idx]
    scale = max(np.abs(Ar).max(), np.abs(Br).max())
    fixed_names = set(p.fixed)
    free, fixed = {}, {}
    for matrix, M, corr, cols in (("A", Ar, corr_A, slow), ("B", Br, corr_B, p.input_names)):
        for i, j in zip(*np.nonzero(np.abs(M) > rtol * scale)):
            entry = f"{p.equation(slow[i])}_{cols[j]}"
            unchanged = abs(corr[i, j]) <= rtol * scale
            # 12 digits: the reduction's rounding noise is not part of the model
            (fixed if entry in fixed_names and unchanged else free)[entry] = float(f"{M[i, j]:.12g}")
    fast_terms = set(fast) | {s + DOT for s in fast}
    outputs = tuple(y for y in p.outputs if not set(p.output_terms(y)) & fast_terms)
    return Profile(
        name=name or f"{p.name} - reduced ({', '.join(fast)} instantaneous)",
        description=f"Residualised from '{p.name}': {', '.join(fast)} taken as instantaneous.",
        states={s: p.states[s] for s in slow}, inputs=dict(p.inputs), outputs=outputs,
        free=free, fixed=fixed,
        output_defs={k: v for k, v in p.output_defs.items() if k in outputs},
        meta={"reduced_from": p.name, "instantaneous_states": list(fast)},
        source=p.source,
        limits={y: v for y, v in p.limits.items() if y in outputs},
    )
