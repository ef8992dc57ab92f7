"""Command-line plumbing shared by ``identify``, ``signaldesign`` and ``cueing``.

Bad input must give one clear line and exit status 2, never a traceback: argparse's own errors
are reduced to one line, and every :class:`PseudostepError` is caught at the top.
"""
from __future__ import annotations

import argparse
import sys

from .errors import PseudostepError

EXIT_BAD_INPUT = 2


class Parser(argparse.ArgumentParser):
    """ArgumentParser whose usage errors are one line on stderr and exit status 2."""

    def error(self, message):  # noqa: D401 - argparse API
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message}\n")


def run(parser: argparse.ArgumentParser, argv=None) -> int:
    """Parse ``argv`` and call ``args.func(args)``; map input errors to one line, status 2."""
    args = parser.parse_args(argv)
    if not hasattr(args, "func"):
        parser.print_help()
        return EXIT_BAD_INPUT
    try:
        return args.func(args) or 0
    except PseudostepError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:  # an output that cannot be written: a bad path, not a bug
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"{parser.prog}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"{parser.prog}: interrupted", file=sys.stderr)
        return 130


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
