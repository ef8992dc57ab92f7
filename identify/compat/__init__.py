"""Flight-path reconstruction (data compatibility checking): ``identify compat``.

Before any aerodynamic model, the measured accelerations and rates are integrated through the
rigid-body kinematics and compared with the measured airspeed, flow angles, attitudes and height;
the sensors' biases, scale factors and time skews that make them agree are estimated (output
error, maximum likelihood), chosen one at a time by score tests, and the corrected runs written.

Layering: above ``refine`` (its score test selects the sensor errors), below nothing else in
``identify``. Modules: :mod:`.kinematics` (the equations and their integration), :mod:`.sensors`
(the sensor-error catalogue and how each acts), :mod:`.fit` (the estimator), :mod:`.report`.
"""
from .fit import Compat, CompatResult
from .kinematics import INPUTS, OUTPUTS
from .sensors import catalogue

__all__ = ["Compat", "CompatResult", "INPUTS", "OUTPUTS", "catalogue"]
