"""Turbulence as the user declares it: the gust states the filter-error method carries.

A profile's ``[turbulence]`` table (or ``identify estimate --method fem --turbulence u,v,w``) lists
the velocities gusts act on. :func:`augment` builds the model the filter-error method fits: one
gust state ``<v>_g`` per listed velocity, first-order Gauss-Markov (Dryden's form for u, a
first-order stand-in for its second-order v and w)::

    d(u_g)/dt = -omega_u u_g + F_u w_u          w_u unit white noise (power spectral density 1)

and every derivative on that velocity acting on the air-relative velocity ``u - u_g``: a parameter
on ``A[:, u]`` gets the entry ``A[:, u_g]`` with the opposite coefficient (a tie, built here; the
free parameters stay the profile's). Each run's initial gusts are estimated with its initial
state (held at 0, a 12 s run's start in a gust is misfitted: over 8 realisations of the S 61
hover with a SAS, benchmarks/filter_error.py, RMS z 1.18 and 2 derivatives beyond 3 std, against
1.10 and none estimated). With ``likelihood = "diffuse"`` the derivatives, corners and
intensities are fitted with the initial states and zero shifts integrated out and each gust's
start a stationary draw (FEM's ``diffuse`` and ``stationary_start``; docs/filter_error.md: on 12
s hover runs it removes the corners' and intensities' bias, with a SAS it lets the u gust's
intensity run up along X_u -> 0, so it is not the default),
the gusts' white forcing is the model's process noise, and the profile's own ``[process_noise]``
(when it declares one) is added to it.

The corner ``omega`` is estimated by default (a hover has no V/L): a free parameter
``corner_<v>_g`` (rad/s, started at ``corner_start``, default 1 rad/s); or held: ``corner``
(rad/s) or ``scale_length`` L with the airspeed V (Dryden's ``omega = V / L``; V from the
table's ``airspeed`` or the runs' ``airspeed`` metadata). The gust's standard deviation (its
intensity) is ``sigma = F / sqrt(2 omega)``.

A profile in flow-angle form (states alpha, beta, no w, v): the wind enters as ``alpha_g = w_g / V``,
``beta_g = v_g / V`` (``--turbulence w`` names the gust on alpha; its intensity is reported in rad,
and in m/s when the airspeed is known). Entries on a velocity column that are kinematic (a height
equation ``h_w``: the inertial velocity) are listed in ``kinematic`` and left alone. Outputs keep
the inertial states; a state derivative in an output (an accelerometer, ``w_dot``) sees the gusts
through A.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace

import numpy as np

from ..errors import EstimationError, ProfileError
from .profile import FLOW_ANGLES, VELOCITY_STATES, Profile, gust_velocity, parse_turbulence

GUST_SUFFIX = "_g"
CORNER_START = 1.0  # rad/s: the estimated corner's default start (correlation time 1 s)
F_SHARE = 0.1  # the gusts' F start: this share of the measured velocity's std, as a gust of that std
CORNER_PREFIX = "corner_"


def with_turbulence(profile: Profile, states: str | list[str]) -> Profile:
    """``profile`` with gusts on ``states`` (``"u,v,w"`` or a list): the command line's
    ``--turbulence``; the rest of an existing ``[turbulence]`` table is kept."""
    listed = [s.strip() for s in states.split(",")] if isinstance(states, str) else list(states)
    table = {**profile.turbulence, "states": [s for s in listed if s]}
    return replace(profile, turbulence=parse_turbulence(table, profile.states, f"{profile.source} (--turbulence)"))


def default_states(profile: Profile) -> list[str]:
    """The velocities FEM gives gust states when nothing is declared (no ``[process_noise]``, no
    ``[turbulence]``): the profile's u, v, w (in flow-angle form alpha for w, beta for v) on whose
    column of A a parameter acts, free or fixed (a gust on a velocity no derivative sees would move
    nothing the data show). Empty: no such velocity."""
    p = profile
    named = set(p.free) | set(p.fixed)
    cols = {en.col for name in named for en, _ in p.parameter_entries(name) if en.matrix == "A"}
    out = []
    for s in VELOCITY_STATES:
        v = gust_velocity(s, p.states)
        if v in p.states and p.state_names.index(v) in cols:
            out.append(v)
    return out


def without(profile: Profile, states) -> Profile:
    """``profile`` with the gusts on ``states`` taken out of its ``[turbulence]`` (and their
    per-state entries); none left: no ``[turbulence]``."""
    t = profile.turbulence
    kept = [s for s in t["states"] if s not in states]
    if not kept:
        return replace(profile, turbulence={})
    table = {k: ({s: x for s, x in v.items() if s in kept} if isinstance(v, dict) else v) for k, v in t.items()}
    return replace(profile, turbulence={**table, "states": kept})


def run_airspeed(runs) -> float | None:
    """The runs' airspeed (m/s) from their ``airspeed`` metadata (``53.6`` or ``53.6 m/s``), the
    mean when they differ; None when no run has one."""
    values = []
    for r in runs:
        text = str(r.meta.get("airspeed", "")).strip()
        if not text:
            continue
        m = re.fullmatch(r"([-+0-9.eE]+)\s*(m/s)?", text)
        if m is None:
            raise EstimationError(f"{r.source}: airspeed metadata '{text}' is not a number in m/s")
        values.append(float(m.group(1)))
    return float(np.mean(values)) if values else None


@dataclass(frozen=True)
class GustModel:
    """The user's ``profile`` and the ``augmented`` one the filter fits: ``gusts`` {velocity:
    gust state}, ``corners`` {velocity: free parameter name} (estimated) and ``held`` {velocity:
    corner rad/s}; ``airspeed`` (m/s or None). The augmented free parameters are the profile's,
    in its order, then the estimated corners."""

    profile: Profile
    augmented: Profile
    gusts: dict
    corners: dict
    held: dict
    airspeed: float | None

    @property
    def diffuse(self) -> bool:
        """The diffuse likelihood declared (``likelihood = "diffuse"``)."""
        return self.profile.turbulence.get("likelihood") == "diffuse"

    @property
    def n_derivatives(self) -> int:
        return len(self.profile.free)

    def describe(self) -> str:
        """The process-noise model in one line."""
        p = self.profile
        how = ", ".join(f"{s}: {'estimated' if s in self.corners else f'{self.held[s]:.4g} rad/s held'}"
                        for s in self.gusts)
        own = f"; and white process noise on {', '.join(p.process_noise)}" if p.process_noise else ""
        return (f"process noise: turbulence, first-order gust states {', '.join(self.gusts.values())} (corner {how}), "
                f"process noise on them, every derivative on {', '.join(self.gusts)} acting on the "
                f"air-relative velocity{own}" + ("; the corners and intensities fitted with each run's initial "
                f"states and zero shifts integrated out (the diffuse likelihood)" if self.diffuse else ""))

    def held_start(self, s: str) -> float:
        """The start value of velocity ``s``'s estimated corner (rad/s)."""
        return float(self.augmented.free[self.corners[s]])

    def noise_states(self) -> dict:
        """FEM's ``process_noise``: the gust states (F start or None) and the profile's own."""
        aug = self.augmented
        return {**self.profile.process_noise, **{g: aug.process_noise.get(g) for g in self.gusts.values()}}

    def report(self, theta: np.ndarray, f: dict, cov: np.ndarray, rows: dict) -> dict:
        """The fitted turbulence: per velocity the corner (rad/s) and the intensity (the gust's std,
        ``F / sqrt(2 omega)``, in the velocity's unit) with their bounds by the delta method on
        ``cov``, the covariance of the augmented unknowns (``rows`` {corner parameter or gust
        state: its row}; an unknown without a row is held or on its boundary: its bound NaN)."""
        out = {}
        for s, g in self.gusts.items():
            c_name = self.corners.get(s)
            omega = float(theta[self.augmented.free_names.index(c_name)]) if c_name else self.held[s]
            F = abs(float(f[g]))
            sigma = F / math.sqrt(2 * omega) if omega > 0 else math.nan
            need = [(c_name, -sigma / (2 * omega))] if c_name else []
            need.append((g, 1 / math.sqrt(2 * omega) if omega > 0 else math.nan))
            idx = [rows.get(k) for k, _ in need]
            if None in idx:
                var = math.nan
            else:
                d = np.array([v for _, v in need])
                var = float(d @ cov[np.ix_(idx, idx)] @ d)
            entry = {"gust_state": g, "corner": omega, "corner_estimated": bool(c_name),
                     "corner_std": (math.sqrt(cov[rows[c_name], rows[c_name]]) if rows.get(c_name) is not None
                                    else math.nan) if c_name else math.nan,  # held: no bound
                     "correlation_time": 1 / omega if omega > 0 else math.inf,
                     "intensity": sigma, "intensity_std": math.sqrt(var) if var > 0 else math.nan,
                     "unit": self.profile.states[s], "F": F}
            if s in FLOW_ANGLES.values() and self.airspeed:  # alpha_g = w_g / V: the gust in m/s too
                entry["intensity_m_s"] = sigma * self.airspeed
            out[s] = entry
        return out

    def fitted_table(self, theta: np.ndarray, f: dict) -> dict:
        """The profile's ``[turbulence]`` with the fitted corners and F as start values (the next
        fit, refine's nested ones, start there)."""
        t = dict(self.profile.turbulence)
        if self.corners:
            # a corner fitted to zero or below is not determined (said with the result): the next
            # fit starts where this one did, not at a value the profile cannot hold
            fitted = {s: float(theta[self.augmented.free_names.index(c)]) for s, c in self.corners.items()}
            t["corner_start"] = {s: w if 0 < w < math.inf else self.held_start(s) for s, w in fitted.items()}
        t["intensity"] = {s: max(abs(float(f[g])), 1e-12) for s, g in self.gusts.items()}
        return t


def augment(profile: Profile, runs=()) -> GustModel:
    """The gust model of a profile with a ``[turbulence]`` declaration (see the module's doc);
    ``runs`` give the airspeed (for ``scale_length``) and the gusts' F start (from the measured
    velocities' std) where the declaration does not."""
    p, t = profile, profile.turbulence
    if not t:
        raise ProfileError(f"{p.source}: no [turbulence] declared")
    gusts = {s: s + GUST_SUFFIX for s in t["states"]}
    clash = [g for g in gusts.values() if g in p.states or g in p.inputs]
    if clash:
        raise ProfileError(f"{p.source}: [turbulence]: the gust state name(s) {', '.join(clash)} are taken")
    airspeed = t.get("airspeed") or run_airspeed(runs)
    held = dict(t.get("corner", {}))
    if "scale_length" in t:
        if not airspeed:
            raise EstimationError(f"{p.source}: [turbulence] scale_length needs the airspeed: give airspeed = "
                                  f"... (m/s) in [turbulence] or an 'airspeed' in the runs' metadata")
        held = dict.fromkeys(gusts, airspeed / t["scale_length"])
    free, fixed, ties = dict(p.free), dict(p.fixed), _relative_ties(p, gusts, set(t.get("kinematic", ())))
    corners = {}
    for s, g in gusts.items():
        entry = f"{g}_{g}"  # a gust state's equation carries its own name
        if s in held:
            fixed[entry] = -held[s]
        else:
            corners[s] = CORNER_PREFIX + g
            free[corners[s]] = t.get("corner_start", {}).get(s, CORNER_START)
            ties[corners[s]] = {entry: -1.0}
    start = _f_start(p, gusts, runs, {s: held.get(s, free.get(corners.get(s), CORNER_START)) for s in gusts})
    aug = replace(p, states={**p.states, **{g: p.states[s] for s, g in gusts.items()}},
                  free=free, fixed=fixed, ties=ties, turbulence={},
                  process_noise={**p.process_noise, **start},
                  initial_state=dict(p.initial_state),
                  name=f"{p.name} + gust states")
    return GustModel(p, aug, gusts, corners, held, airspeed)


def _relative_ties(p: Profile, gusts: dict, kinematic: set) -> dict:
    """The profile's ties with every parameter on a gust velocity's column of A also acting, with
    the opposite coefficient, on the gust's column (the air-relative velocity), except the
    ``kinematic`` entries (or parameters)."""
    cols = {p.state_names.index(s): g for s, g in gusts.items()}
    named = set(p.free) | set(p.fixed)
    for k in kinematic:
        if k not in named:
            p.parse_entry(k)  # an entry name, else ProfileError
    ties = dict(p.ties)
    for name in named - kinematic:
        entries = p.ties.get(name, {name: 1.0})
        added = {}
        for e, c in entries.items():
            en = p.parse_entry(e)
            if en.matrix == "A" and en.col in cols and e not in kinematic:
                added[f"{p.equation(p.state_names[en.row])}_{cols[en.col]}"] = -c
        if added:
            ties[name] = {**entries, **added}
    return ties


def _f_start(p: Profile, gusts: dict, runs, corners: dict) -> dict:
    """F starts of the gust states: the declared ``intensity``, else F_SHARE of the measured
    velocity's std as a gust of that std (``F = sigma sqrt(2 omega)``); unmeasured: not given (the
    estimator chooses)."""
    given = p.turbulence.get("intensity", {})
    out = {}
    for s, g in gusts.items():
        if s in given:
            out[g] = given[s]
            continue
        if s in p.outputs and p.output_terms(s) == {s: 1.0} and runs:
            data = np.concatenate([np.asarray(r[s], float) for r in runs])
            std = float(np.nanstd(data))
            if std > 0:
                out[g] = F_SHARE * std * math.sqrt(2 * corners[s])
    return out
