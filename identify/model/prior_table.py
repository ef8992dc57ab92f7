"""The ``[prior]`` table of a profile, parsed and written (the rest of a priori weighting's
declaration, relative priors and priors from files, is :mod:`identify.model.prior`)."""
from __future__ import annotations

import json
import math

from ..errors import ProfileError


def parse_prior(table, free: dict[str, float], source: str) -> dict[str, dict[str, float]]:
    """``[prior]`` as ``{name: {"value", "std"}}``; one ProfileError naming the entry at fault."""
    if not isinstance(table, dict):
        raise ProfileError(f"{source}: [prior] must be a table of parameter = std or {{ value = ..., std = ... }}")
    out = {}
    for name, spec in table.items():
        if name not in free:
            raise ProfileError(f"{source}: [prior] {name}: not a free parameter (free: {', '.join(free)})")
        if isinstance(spec, dict):
            if set(spec) - {"value", "std"} or "std" not in spec:
                raise ProfileError(f"{source}: [prior] {name} = {spec!r}: expected {{ value = ..., std = ... }}")
            value, std = spec.get("value", free[name]), spec["std"]
        else:
            value, std = free[name], spec
        for what, v in (("value", value), ("std", std)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ProfileError(f"{source}: [prior] {name}: {what} {v!r} is not a finite number")
        if not std > 0:
            raise ProfileError(f"{source}: [prior] {name}: std {std!r} must be positive "
                               f"(a known value belongs in [fixed])")
        out[name] = {"value": float(value), "std": float(std)}
    return out


def prior_toml_lines(prior: dict[str, dict[str, float]]) -> list[str]:
    """The ``[prior]`` table as TOML lines (centres written out), empty when there is none."""
    if not prior:
        return []
    return ["", "[prior]"] + [f"{_key(k)} = {{ value = {v['value']!r}, std = {v['std']!r} }}"
                              for k, v in prior.items()]


def _key(k: str) -> str:
    return k if all(c.isalnum() or c in "_-" for c in k) else json.dumps(k)
