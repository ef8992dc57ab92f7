"""The cueing layer's input errors (one clear line, exit status 2 on the command line)."""
from identify.errors import PseudostepError


class CueingError(PseudostepError):
    """Bad cueing input: unknown source, missing device, unreadable flight log, bad option."""
