"""Units of measured channels: a small table converting flight-test units to SI, and a check that
an angle channel taken as radians does not hold degrees.

Every run channel is used in SI units and radians. A file may declare other units per channel
(``deg``, ``deg/s``, ``ft``, ``kt``, ``g`` ...); :func:`to_si` converts them on read. The table is
deliberately small and exact (only multiplicative factors, no offsets such as degrees Celsius):
that is all flight-test channels need. ``pint`` was considered and not used: it does not know the
flight-test spellings (``rps`` and ``dps`` for rad/s and deg/s, ``KTAS``, ``lbs`` for force), so a
table of aliases would be needed anyway, and its import (about 0.3 s) would cost a fifth of the
whole ``identify estimate`` process.
"""
from __future__ import annotations

import math
import re

import numpy as np

from ..errors import RunError

G0 = 9.80665  # standard gravity, m/s^2 (the exact value that defines the unit g)
FT = 0.3048  # m, exact
KT = 1852.0 / 3600.0  # m/s, exact
DEG = math.pi / 180.0

# canonical unit -> (factor to SI, quantity); SI value = factor * value in the unit
UNITS: dict[str, tuple[float, str]] = {
    # angles
    "rad": (1.0, "angle"), "deg": (DEG, "angle"), "mrad": (1e-3, "angle"), "rev": (2 * math.pi, "angle"),
    # angular rates
    "rad/s": (1.0, "angular rate"), "deg/s": (DEG, "angular rate"), "rpm": (2 * math.pi / 60, "angular rate"),
    "rev/s": (2 * math.pi, "angular rate"),
    # angular accelerations
    "rad/s^2": (1.0, "angular acceleration"), "deg/s^2": (DEG, "angular acceleration"),
    # lengths
    "m": (1.0, "length"), "ft": (FT, "length"), "in": (0.0254, "length"), "cm": (0.01, "length"),
    "mm": (1e-3, "length"), "km": (1e3, "length"), "nmi": (1852.0, "length"),
    # speeds
    "m/s": (1.0, "speed"), "ft/s": (FT, "speed"), "kt": (KT, "speed"), "km/h": (1 / 3.6, "speed"),
    "mph": (0.44704, "speed"), "ft/min": (FT / 60, "speed"),
    # accelerations
    "m/s^2": (1.0, "acceleration"), "ft/s^2": (FT, "acceleration"), "g": (G0, "acceleration"),
    # time
    "s": (1.0, "time"), "ms": (1e-3, "time"), "us": (1e-6, "time"), "min": (60.0, "time"),
    "day": (86400.0, "time"),  # a MATLAB datenum counts days
    # forces, pressures
    "n": (1.0, "force"), "lbf": (4.4482216152605, "force"),
    "pa": (1.0, "pressure"), "kpa": (1e3, "pressure"), "hpa": (100.0, "pressure"), "mbar": (100.0, "pressure"),
    "psf": (4.4482216152605 / FT ** 2, "pressure"), "psi": (4.4482216152605 / 0.0254 ** 2, "pressure"),
    # dimensionless (stick travel in % becomes a fraction)
    "1": (1.0, "dimensionless"), "%": (0.01, "dimensionless"),
}

_ALIASES = {
    "radian": "rad", "radians": "rad", "degree": "deg", "degrees": "deg", "°": "deg",
    "dps": "deg/s", "°/s": "deg/s", "fps": "ft/s", "kn": "kt", "kts": "kt", "knot": "kt", "knots": "kt",
    "kph": "km/h", "kmh": "km/h", "fpm": "ft/min", "feet": "ft", "foot": "ft", "inch": "in",
    "meter": "m", "metre": "m", "meters": "m", "metres": "m", "sec": "s", "second": "s", "seconds": "s",
    "-": "1", "": "1", "none": "1", "nd": "1", "percent": "%", "g's": "g", "gs": "g", "lb": "lbf",
    # as flight-test data (NASA's SIDPAC among them) writes them: rps and dps are radians and degrees
    # per second, KTAS/KIAS/KCAS knots of true/indicated/calibrated airspeed, lbs pound-force
    "rps": "rad/s", "1/s": "rad/s", "1/sec": "rad/s", "ktas": "kt", "kias": "kt", "kcas": "kt", "keas": "kt",
    "lbs": "lbf", "pound": "lbf", "pounds": "lbf", "lb/ft^2": "psf", "lbf/ft^2": "psf", "lb/in^2": "psi",
    "rad/s/s": "rad/s^2", "deg/s/s": "deg/s^2", "m/s/s": "m/s^2", "ft/s/s": "ft/s^2", "dps2": "deg/s^2",
    "rps2": "rad/s^2", "fps2": "ft/s^2",
}

# The largest magnitude a channel truly in SI can reach in a flight-test run, per angular quantity.
# Above it the values look like degrees. Reasons (documented in the README):
#   angle: |x| > pi rad (180 deg): no pitch, roll or flow angle in a run a linear model describes
#          reaches half a turn (a heading wrapped to 0..360 deg would; declare it);
#   control angle (a profile input in rad): |x| > pi/2 rad (90 deg): no control surface or blade
#          pitch deflects a quarter turn (elevators and cyclic pitch stay within about 30 deg);
#   rate: |x| > 2 pi rad/s (360 deg/s): a full turn per second exceeds the body rates of any piloted
#          aircraft (fighter roll rates peak near 300 deg/s);
#   acceleration: |x| > 6 pi rad/s^2 (1080 deg/s^2): well above the largest angular accelerations
#          control inputs produce (helicopters reach a few rad/s^2, fighters about 10).
DEGREE_LIMITS = {"angle": math.pi, "control angle": math.pi / 2, "angular rate": 2 * math.pi,
                 "angular acceleration": 6 * math.pi}
_LIMIT_TEXT = {"angle": "pi rad (180 deg)", "control angle": "pi/2 rad (90 deg) for a control deflection",
               "angular rate": "2 pi rad/s (360 deg/s)", "angular acceleration": "6 pi rad/s^2 (1080 deg/s^2)"}


def canonical(unit: str) -> str | None:
    """The table's spelling of ``unit`` (case, spaces, ``sec``, ``s2``, ``²`` forgiven), or None."""
    u = str(unit).strip().lower().replace(" ", "").replace("²", "^2").replace("**", "^")
    u = _ALIASES.get(u, u)
    u = re.sub(r"/sec(?=/)", "/s", u)
    u = re.sub(r"/sec(\^?2)?$", lambda m: "/s" + ("^2" if m.group(1) else ""), u)
    u = re.sub(r"/s2$", "/s^2", u)
    u = re.sub(r"/s/s$", "/s^2", u)
    u = _ALIASES.get(u, u)
    u = re.sub(r"^(degrees|degree|°)/", "deg/", u)
    u = re.sub(r"^(radians|radian)/", "rad/", u)
    u = re.sub(r"^(feet|foot)/", "ft/", u)
    return u if u in UNITS else None


def unit_info(unit: str, where: str) -> tuple[str, float, str]:
    """``(canonical unit, factor to SI, quantity)``; RunError naming ``where`` if unknown."""
    u = canonical(unit)
    if u is None:
        raise RunError(f"{where}: unknown unit '{unit}' (known: {', '.join(UNITS)})")
    factor, quantity = UNITS[u]
    return u, factor, quantity


def to_si(values: np.ndarray, unit: str, where: str) -> np.ndarray:
    """``values`` (any shape) given in ``unit`` converted to SI units and radians."""
    _, factor, _ = unit_info(unit, where)
    return np.asarray(values, dtype=float) * factor


def si_unit(unit: str) -> str:
    """The SI unit of ``unit``'s quantity (``deg/s`` -> ``rad/s``; ``SI`` for a unit not known)."""
    kind = quantity(unit)
    return next((u for u, (factor, q) in UNITS.items() if q == kind and factor == 1.0), "SI")


def quantity(unit: str) -> str | None:
    """The quantity a unit measures (``angle``, ``speed`` ...), or None for a unit not in the table."""
    u = canonical(unit)
    return None if u is None else UNITS[u][1]


def parse_units_spec(text: str, where: str) -> dict[str, str]:
    """``"q=deg/s, theta = deg"`` (the ``# units:`` metadata line) as ``{channel: unit}``."""
    out = {}
    for item in filter(None, (s.strip() for s in str(text).split(","))):
        name, sep, unit = item.partition("=")
        if not sep or not name.strip():
            raise RunError(f"{where}: units entry '{item}' is not 'channel=unit'")
        unit_info(unit, f"{where}: channel '{name.strip()}'")
        out[name.strip()] = unit.strip()
    return out


def looks_like_degrees(values: np.ndarray, kind: str) -> float | None:
    """The peak |value| when a channel taken as SI ``kind`` (an angular quantity) exceeds the
    physical limit for radians (:data:`DEGREE_LIMITS`), else None."""
    limit = DEGREE_LIMITS.get(kind)
    if limit is None or values.size == 0:
        return None
    peak = float(np.max(np.abs(values)))
    return peak if peak > limit else None


DEGREE_UNIT = {"angle": "deg", "control angle": "deg", "angular rate": "deg/s", "angular acceleration": "deg/s^2"}


def declare_hint(channel: str, unit: str, file_format: str) -> str:
    """How to declare ``channel``'s unit in a file of ``file_format`` (``csv`` or ``mat``)."""
    if file_format == "mat":
        return f'the channel map\'s "units": {{"{channel}": "{unit}"}}'
    return f"'# units: {channel}={unit}' on top of the file, a header '{channel} [{unit}]' or the channel map's \"units\""


def degree_warning(source: str, channel: str, peak: float, kind: str, how: str, file_format: str = "csv") -> str:
    """The one-line warning for a channel whose radian values look like degrees."""
    return (f"{source}: channel '{channel}' ({how}) reaches |{peak:.4g}|, beyond {_LIMIT_TEXT[kind]}: "
            f"it looks like {DEGREE_UNIT[kind]}; declare its unit ({declare_hint(channel, DEGREE_UNIT[kind], file_format)})")
