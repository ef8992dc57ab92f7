"""The cueing layer's input errors (one clear line, exit status 2 on the command line); the class
lives with every layer's errors in :mod:`identify.errors`."""
from identify.errors import CueingError

__all__ = ["CueingError"]
