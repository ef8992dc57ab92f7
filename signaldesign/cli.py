"""``python -m signaldesign``: frequency band, signal design, baselines, comparison, plots."""
from __future__ import annotations

from identify.cliutil import Parser, run


def build_parser() -> Parser:
    parser = Parser(prog="signaldesign", description="Design flight-test input signals from an a priori model.")
    parser.add_subparsers(title="commands")
    return parser


def main(argv=None) -> int:
    return run(build_parser(), argv)
