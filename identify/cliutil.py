"""Command-line plumbing shared by ``identify``, ``signaldesign`` and ``cueing``.

Bad input must give one clear line and exit status 2, never a traceback: argparse's own errors
are reduced to one line, and every :class:`PseudostepError` is caught at the top. Output paths
are checked while the arguments are parsed (:func:`output_dir`, :func:`output_file`), before any
work, so a mistyped folder never costs a computed result. Warnings (non-convergence, ...) are one
line each on stderr. BLAS runs ``--threads`` threads (default 1): the commands' matrices are small,
and threaded BLAS on a busy machine only adds contention (threadpoolctl sets it at run time, which
also holds when ``main(argv)`` is called in a process that has loaded numpy already).

This module imports no numpy: ``--help`` must answer at once.
"""
from __future__ import annotations

import argparse
import os
import sys
import warnings
from pathlib import Path

from ._version import __version__
from .errors import PseudostepError

EXIT_BAD_INPUT = 2
EXIT_NUMERICAL = 1  # a computation that failed on valid input (a singular matrix, an SVD that did not converge)
EXIT_BROKEN_PIPE = 141  # as a shell reports a program ended by SIGPIPE (``cmd | head``)
DEFAULT_THREADS = 1


def _writable_dir(path: Path) -> bool:
    return path.is_dir() and os.access(path, os.W_OK | os.X_OK)


def output_dir(text: str) -> str:
    """argparse type of an output folder: an existing writable folder, or one that can be
    created (its nearest existing ancestor is a writable folder)."""
    path = Path(text)
    if not text.strip():
        raise argparse.ArgumentTypeError("empty output folder name")
    if path.exists():
        if not _writable_dir(path):
            raise argparse.ArgumentTypeError(f"{text}: " + ("not a folder" if not path.is_dir() else "folder not writable"))
        return text
    parent = path.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not _writable_dir(parent):
        raise argparse.ArgumentTypeError(f"{text}: cannot create the folder ({parent} is "
                                         f"{'not a folder' if not parent.is_dir() else 'not writable'})")
    return text


def output_file(text: str) -> str:
    """argparse type of an output file: not a folder, in an existing writable folder."""
    path = Path(text)
    if not text.strip() or path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r}: is a folder, not a file name" if text.strip() else "empty file name")
    if path.exists() and not os.access(path, os.W_OK):
        raise argparse.ArgumentTypeError(f"{text}: file not writable")
    folder = path.absolute().parent
    if not _writable_dir(folder):
        raise argparse.ArgumentTypeError(f"{text}: folder {folder} " + ("does not exist" if not folder.exists()
                                                                       else "is not a writable folder"))
    return text


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if value != value or value in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"must be finite, got {text}")
    return value


def finite_float(text: str) -> float:
    """argparse type: a finite number."""
    return _number(text)


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    value = _number(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text}")
    return value


def nonnegative_float(text: str) -> float:
    """argparse type: a finite number >= 0."""
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must not be negative, got {text}")
    return value


def state_values(text: str) -> dict[str, float]:
    """argparse type: ``name=value,name=value`` (known initial states)."""
    out = {}
    for item in text.split(","):
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise argparse.ArgumentTypeError(f"expected STATE=VALUE[,STATE=VALUE...], got {text!r}")
        out[name.strip()] = _number(value)
    return out


def fraction(text: str) -> float:
    """argparse type: a number within 0..1."""
    value = _number(text)
    if not 0 <= value <= 1:
        raise argparse.ArgumentTypeError(f"must be within 0..1, got {text}")
    return value


def _integer(text: str, minimum: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < minimum:
        raise argparse.ArgumentTypeError(f"must be at least {minimum}, got {value}")
    return value


def nonnegative_int(text: str) -> int:
    """argparse type: an integer >= 0."""
    return _integer(text, 0)


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    return _integer(text, 1)


def add_threads_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--threads", type=positive_int, default=DEFAULT_THREADS, metavar="N",
                        help=f"BLAS threads for the numerical work (default {DEFAULT_THREADS})")


class Parser(argparse.ArgumentParser):
    """ArgumentParser whose usage errors are one line on stderr and exit status 2, with
    ``--version`` on the command and on every subcommand (argparse makes them of this class)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.add_argument("--version", action="version", version=f"{self.prog.split()[0]} (pseudostep) {__version__}")

    def parse_known_args(self, args=None, namespace=None):
        self._argv = list(sys.argv[1:] if args is None else args)
        return super().parse_known_args(args, namespace)

    def error(self, message):  # noqa: D401 - argparse API
        # the program's name alone, as for every other error line ("cueing: error: ...")
        self.exit(EXIT_BAD_INPUT, f"{self.prog.split()[0]}: error: {' '.join(message.split())}{self._greedy_hint(message)}\n")

    def _greedy_hint(self, message: str) -> str:
        """Why the runs went missing: an option taking several files (``--validate RUN ...``) took
        every file after it. Never guessed apart: which file was meant for which is the user's call."""
        required = message.partition("the following arguments are required:")[2]
        if not any(name.strip() and not name.strip().startswith("-") for name in required.split(",")):
            return ""  # only a positional (the runs) can have been taken
        greedy = [a.option_strings[0] for a in self._actions
                  if a.option_strings and a.nargs in ("+", "*") and set(a.option_strings) & set(getattr(self, "_argv", []))]
        if not greedy:
            return ""
        return f" ({greedy[0]} takes every file after it: put it after the runs)"


def run(parser: argparse.ArgumentParser, argv=None) -> int:
    """Parse ``argv`` and call ``args.func(args)``; map input errors to one line, status 2.
    Returns the exit status (also for usage errors and ``--help``, which argparse exits on)."""
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else EXIT_BAD_INPUT
    if not hasattr(args, "func"):
        parser.print_help()
        return EXIT_BAD_INPUT
    try:
        with warnings.catch_warnings(), _blas_threads(getattr(args, "threads", DEFAULT_THREADS)):
            warnings.showwarning = _one_line(parser.prog)
            status = args.func(args) or 0
            sys.stdout.flush()  # a closed pipe shows here, not at interpreter exit
            return status
    except BrokenPipeError:  # the reader went away (``| head``): nothing left to say, and no one to say it to
        _stdout_to_devnull()
        return EXIT_BROKEN_PIPE
    except PseudostepError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except UnicodeDecodeError as exc:  # a binary file where text was expected (a reader that did not say which)
        print(f"{parser.prog}: error: an input file is not UTF-8 text ({exc.reason} at byte {exc.start})",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    except ValueError as exc:
        if type(exc).__name__ != "LinAlgError":  # numpy's (not imported here: --help stays fast)
            raise
        # a computation that failed on valid input (a singular matrix, an SVD that did not converge)
        print(f"{parser.prog}: error: numerical failure, not an input error: {exc}", file=sys.stderr)
        return EXIT_NUMERICAL
    except OSError as exc:  # an output that cannot be written: a bad path, not a bug
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"{parser.prog}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"{parser.prog}: interrupted", file=sys.stderr)
        return 130
    except SystemExit as exc:  # a signal made an exit during the work (cueing's run under SIGTERM)
        if isinstance(exc.code, int) and exc.code > 128:
            print(f"{parser.prog}: terminated (signal {exc.code - 128})", file=sys.stderr)
        raise


def _stdout_to_devnull() -> None:
    """Point stdout at /dev/null so the interpreter's final flush of a closed pipe stays silent."""
    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def _one_line(prog: str):
    """A ``warnings.showwarning`` that writes ``prog: warning: message`` as one line on stderr."""
    def show(message, category, filename, lineno, file=None, line=None):
        text = " ".join(str(message).split())
        print(f"{prog}: warning: {text}", file=sys.stderr, flush=True)
    return show


def _blas_threads(n: int):
    """Context capping BLAS at ``n`` threads. threadpoolctl acts on the BLAS libraries already
    loaded, so numpy is loaded first (the environment variables cover a BLAS loaded with it)."""
    if "numpy" not in sys.modules:
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ[var] = str(n)
    import numpy  # noqa: F401 - loads the BLAS that threadpoolctl then limits
    from threadpoolctl import threadpool_limits
    return threadpool_limits(limits=n, user_api="blas")


def progress_bar(label: str, stream=None, width: int = 30):
    """A ``progress(i, total)`` callback drawing a one-line text progress bar on stderr."""
    def show(i: int, total: int) -> None:
        out = stream or sys.stderr
        filled = int(width * i / max(total, 1))
        out.write(f"\r{label} [{'#' * filled}{'.' * (width - filled)}] {i}/{total}")
        if i >= total:
            out.write("\n")
        out.flush()
    return show
