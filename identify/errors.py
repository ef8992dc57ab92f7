"""Every layer's input errors: the command lines turn each into one clear line and exit status 2.

Every error pseudostep raises on bad input derives from :class:`PseudostepError` (also a
``ValueError``: a bad value given by the user); its message names the file, row, channel,
parameter or state at fault, so the user never needs a traceback. The upper layers' classes live
here too (one hierarchy in one place) and are re-exported where they are used
(``signaldesign.SignalError``, ``cueing.errors.CueingError``).
"""


class PseudostepError(ValueError):
    """Base class for errors caused by the user's input, not by a bug."""


# -- identify -------------------------------------------------------------------------------------
class ProfileError(PseudostepError):
    """A profile (a priori model TOML) is malformed."""


class RunError(PseudostepError):
    """A run file (measured data) is malformed or lacks a channel."""


class SimulationError(PseudostepError):
    """A simulation diverged or cannot be carried out."""


class EstimationError(PseudostepError):
    """An estimator cannot proceed (unidentifiable parameters, too few samples, divergence)."""


# -- signaldesign ---------------------------------------------------------------------------------
class SignalError(PseudostepError):
    """A signal file or a signal's definition is invalid."""


class BandError(PseudostepError):
    """The required frequency band cannot be derived (no modes to excite, bad options)."""


class DesignError(PseudostepError):
    """A design or evaluation is impossible as asked (constraints, durations, inputs)."""


# -- cueing ---------------------------------------------------------------------------------------
class CueingError(PseudostepError):
    """Bad cueing input: unknown source, missing device, unreadable flight log, bad option."""


# -- campaign -------------------------------------------------------------------------------------
class CampaignError(PseudostepError):
    """A campaign manifest, test matrix or campaign option is invalid."""


def read_text(path, error: type[PseudostepError], what: str) -> str:
    """The text of the file ``path``; an unreadable or binary file raises one ``error`` naming
    ``what`` the file should have been (``"profile"``, ``"frame log"``)."""
    from pathlib import Path

    path = Path(path)
    try:
        return path.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise error(f"{path}: cannot read {what} ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise error(f"{path}: not a {what} (binary, not UTF-8 text)") from None


class ConvergenceWarning(UserWarning):
    """An iterative estimator stopped before convergence: its estimates are not final. The result
    says so too (``info["converged"]`` False, the reason in ``info["stop"]`` and ``summary()``)."""
