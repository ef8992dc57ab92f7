"""The cueing layer's errors: bad input (one clear line, exit status 2 on the command line), and a
run the pilot ended before anything could be written (exit status 3, as any aborted run)."""
from identify.errors import PseudostepError


class CueingError(PseudostepError):
    """Bad cueing input: unknown source, missing device, unreadable flight log, bad option."""


class RunAborted(CueingError):
    """The pilot ended the run (Escape, closed window) before the signal's start: no run file."""
