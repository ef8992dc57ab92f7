"""A priori weighting: what the wind tunnel or the last flight knew, as a Gaussian per parameter.

A profile's ``[prior]`` table gives free parameters a prior distribution (Maine & Iliff's a priori
weighting, Morelli & Klein's mixed estimation)::

    [prior]
    M_q = 0.4                            # std around its [free] value
    L_v = { value = 0.0, std = 0.02 }    # its own centre (the fit still starts at [free])

The parsed table is ``Profile.prior``: ``{name: {"value": centre, "std": std}}`` with the centre
written out (a profile whose [free] values later move -- an identified model, refine's start --
keeps the prior where it was). Parameters without an entry have no prior (the data alone).

:func:`relative_prior` gives every free parameter one (``--prior-relative PCT``) and
:func:`prior_from_file` takes a previous result's estimates and standard errors (``--prior FILE``).
"""
from __future__ import annotations

import json
import math
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

from ..errors import ProfileError, read_text
from .profile import parse_profile
from .prior_table import parse_prior
from .schedule import schedule_of


def with_prior(profile, prior: dict[str, dict[str, float]]):
    """``profile`` with ``prior`` entries added (replacing those it had for the same parameters);
    entries for parameters that are not free are refused."""
    kept = {k: v for k, v in profile.prior.items() if k in profile.free}  # --fix may have held some
    table = {**kept, **{k: dict(v) for k, v in prior.items()}}
    return replace(profile, prior=parse_prior(table, profile.free, profile.source))


# -- --prior-relative -------------------------------------------------------------------------
KIN_FLOOR = 0.1  # a near-zero parameter's std: percent % of a tenth of its largest kin's magnitude


def relative_prior(profile, percent: float) -> tuple[dict[str, dict[str, float]], list[str]]:
    """Every free parameter's prior: centre its [free] value, std ``percent`` % of the larger of
    its own magnitude and the floor, ``KIN_FLOOR`` (a tenth) of the largest a priori magnitude of
    its *kin* -- the free parameters on the same equation and on a variable of the same unit
    (``L_u``, ``L_v``, ``L_w`` are kin: one equation, velocities in m/s). The floor keeps a
    derivative whose a priori value is near zero (a coupling term) from a prior that would pin it
    to exactly that value. A parameter whose kin are all zero gets no prior (listed in the second
    return, to be said). A tie (a parameter acting on several entries) is its own kin."""
    if not (math.isfinite(percent) and percent > 0):
        raise ProfileError(f"--prior-relative: the percentage must be positive, got {percent!r}")
    kin = defaultdict(list)
    for name, value in profile.free.items():
        kin[_kin_key(profile, name)].append(abs(value))
    out, none = {}, []
    for name, value in profile.free.items():
        scale = max(abs(value), KIN_FLOOR * max(kin[_kin_key(profile, name)]))
        if scale == 0:
            none.append(name)
            continue
        out[name] = {"value": float(value), "std": percent / 100 * scale}
    return out, none


def _kin_key(profile, name: str):
    if name in profile.ties:
        return ("tie", name)
    entry = profile.parse_entry(name)
    cols = profile.states if entry.matrix in "AC" else profile.inputs
    return entry.matrix, entry.row, cols[list(cols)[entry.col]]


# -- --prior FILE -----------------------------------------------------------------------------
def prior_from_file(path: str | Path, profile) -> tuple[dict[str, dict[str, float]], list[str]]:
    """The prior a previous identification gives: from a ``result.json`` (its estimates and
    standard errors) or a profile TOML whose ``meta.std`` holds standard errors (a stitched model
    at a condition). Returns ``{name: {"value", "std"}}`` for the free parameters of ``profile``
    the file gives with a finite positive std, and the free parameters it leaves without a prior
    (to be said)."""
    path = Path(path)
    values, stds = _read_estimates(path)
    out, missing = {}, []
    for name in profile.free:
        v, s = values.get(name), stds.get(name)
        if v is None or s is None or not (math.isfinite(v) and math.isfinite(s) and s > 0):
            missing.append(name)
        else:
            out[name] = {"value": float(v), "std": float(s)}
    if not out:
        raise ProfileError(f"{path}: gives no free parameter of '{profile.name}' a value with a finite std")
    return out, missing


def _read_estimates(path: Path) -> tuple[dict, dict]:
    text = read_text(path, ProfileError, "prior (result.json or profile)")
    if path.suffix.lower() == ".json":
        try:
            params = json.loads(text)["parameters"]
            return ({n: p["value"] for n, p in params.items()},
                    {n: p["std"] for n, p in params.items() if p.get("std") is not None})
        except (ValueError, KeyError, TypeError) as exc:
            raise ProfileError(f"{path}: not a result.json that identify wrote ({exc})") from None
    prof = parse_profile(text, source=str(path))
    if schedule_of(prof) is not None:
        raise ProfileError(f"{path}: a scheduled (stitched) profile: take it at the test point's condition first "
                           f"(identify model {path.name} --at <condition>=<value> --save <file>)")
    std = prof.meta.get("std")
    if not isinstance(std, dict) or not std:
        raise ProfileError(f"{path}: the profile holds no standard errors (meta.std); a prior needs them: "
                           f"use the result.json of its identification")
    return prof.parameters, {k: float(v) for k, v in std.items()}


def prior_options(profile, relative: float | None = None, file: str | Path | None = None):
    """``profile`` with the command line's prior: ``--prior FILE`` (a previous identification's
    estimates and stds) and/or ``--prior-relative PCT`` (every free parameter; with a file, only
    those the file leaves without one), over the profile's own ``[prior]`` entries. Returns the
    profile and the lines to say (what got a prior, what has none)."""
    lines, prior = [], {}
    if file is not None:
        prior, missing = prior_from_file(file, profile)
        lines.append(f"--prior {file}: {len(prior)} parameters from its estimates and stds"
                     + (f"; none for {', '.join(missing)}" if missing else ""))
    if relative is not None:
        rel, none = relative_prior(profile, relative)
        added = {k: v for k, v in rel.items() if k not in prior}
        prior = {**added, **prior}
        lines.append(f"--prior-relative {relative:g}: {len(added)} parameters, std {relative:g} % of the a priori value "
                     f"(at least of a tenth of the largest of its equation's and unit's)"
                     + (f"; none for {', '.join(none)} (a priori zero, and so are its kin)" if none else ""))
    return (with_prior(profile, prior) if prior else profile), lines
