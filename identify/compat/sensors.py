"""The sensor errors flight-path reconstruction can estimate, and how each acts.

* ``b_<input>``: a bias of an accelerometer or rate gyro: the true input is ``measured - b``;
* ``b_<output>``: a bias of an air-data, attitude or height sensor: ``measured = ... + b``;
* ``K_<output>``: a scale factor of the airspeed or a flow-angle vane (``V``, ``alpha``, ``beta``):
  ``measured = K x true`` (estimated as ``K - 1``, zero when absent);
* ``tau_<output>``: a time skew of the same channels: ``measured(t) = true(t - tau)`` (a lagging
  sensor or a logger that stamps it late has ``tau > 0``).

So the modelled output is ``y(t) = K y_kin(t - tau) + b`` with ``y_kin`` from the kinematics
driven by the bias-corrected inputs. Each error is a candidate the score test can add; none is in
the model until the residuals ask for it.
"""
from __future__ import annotations

from dataclasses import dataclass

from .kinematics import INPUTS, OUTPUTS

SCALED = ("V", "alpha", "beta")  # air data: vanes and the pitot are calibrated in flight, attitudes are not
ANGULAR = {"alpha", "beta", "phi", "theta", "psi", "p", "q", "r"}


@dataclass(frozen=True)
class SensorError:
    """One sensor error: ``kind`` ``bias``, ``scale`` or ``skew`` on ``channel``."""

    kind: str
    channel: str

    @property
    def name(self) -> str:
        return {"bias": "b", "scale": "K", "skew": "tau"}[self.kind] + "_" + self.channel

    @property
    def on_input(self) -> bool:
        return self.channel in INPUTS

    @property
    def unit(self) -> str:
        if self.kind == "scale":
            return "1"
        if self.kind == "skew":
            return "s"
        return {"a_x": "m/s^2", "a_y": "m/s^2", "a_z": "m/s^2", "p": "rad/s", "q": "rad/s", "r": "rad/s",
                "V": "m/s", "h": "m"}.get(self.channel, "rad")

    def display(self, value: float) -> float:
        """``value`` as reported: a scale factor as K (not K - 1)."""
        return 1.0 + value if self.kind == "scale" else value


def catalogue(inputs=INPUTS, outputs=OUTPUTS) -> list[SensorError]:
    """Every sensor error the channels present allow: biases of every input and output, scale
    factors and time skews of the air data."""
    out = [SensorError("bias", c) for c in inputs]
    out += [SensorError("bias", c) for c in outputs]
    out += [SensorError("scale", c) for c in SCALED if c in outputs]
    out += [SensorError("skew", c) for c in SCALED if c in outputs]
    return out


def by_name(name: str, inputs=INPUTS, outputs=OUTPUTS) -> SensorError:
    for e in catalogue(inputs, outputs):
        if e.name == name:
            return e
    from ..errors import EstimationError

    raise EstimationError(f"compat: unknown sensor error '{name}' (known: "
                          f"{', '.join(e.name for e in catalogue(inputs, outputs))})")
