"""The cueing layer's errors: bad input (one clear line, exit status 2 on the command line; the class
lives with every layer's errors in :mod:`identify.errors`), and a run the pilot ended before anything
could be written (exit status 3, as any aborted run)."""
from identify.errors import CueingError

__all__ = ["CueingError", "RunAborted"]


class RunAborted(CueingError):
    """The pilot ended the run (Escape, closed window) before the signal's start: no run file."""
