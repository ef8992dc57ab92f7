"""The benchmarks' command line, shared: not a benchmark (``make benchmarks`` skips ``_*.py``).

Every script in benchmarks/ builds its parser with :func:`parser` in a function ``parser()`` of its
own, so that ``--help`` prints what the script measures (its docstring) and every option with its
default, and tests/test_benchmarks_cli.py can parse the Makefile's reduced arguments with it
without running anything.
"""
from __future__ import annotations

import argparse


class _Formatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """The docstring as written; each option's default after its help."""


def parser(doc: str) -> argparse.ArgumentParser:
    """A parser whose description is the script's docstring (what it measures)."""
    return argparse.ArgumentParser(description=doc, formatter_class=_Formatter)


def count(text: str) -> int:
    """An argument type: a whole number >= 0 (realisations, seeds, points; 0 where a script skips)."""
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text}: a count >= 0")
    return value


def positive(text: str) -> float:
    """An argument type: a number > 0 (a duration, a record length)."""
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text}: a number > 0")
    return value


def counted(doc: str, name: str, default: int, help: str) -> argparse.ArgumentParser:
    """A parser with an optional positional count (``script.py 10``), as the Makefile and the docs
    pass it: realisations, seeds, points."""
    ap = parser(doc)
    ap.add_argument(name, nargs="?", type=count, default=default, help=help)
    return ap


def add_parts(ap: argparse.ArgumentParser, name: str, parts: str, help: str) -> None:
    """An optional positional selection of numbered parts, e.g. ``13`` of ``123`` (all by default)."""
    def selection(text: str) -> str:
        if not text or set(text) - set(parts):
            raise argparse.ArgumentTypeError(f"{text!r}: digits among {parts}")
        return text

    ap.add_argument(name, nargs="?", type=selection, default=parts, help=f"{help}, any of {parts}")
