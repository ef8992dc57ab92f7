"""``python -m identify``: inspect models and identify them from runs.

Argument parsing and printing only: each command group is a module of :mod:`identify.commands`
(``add_parser(sub)`` and the function it runs); the work lives in :mod:`identify.pipeline` and below.
A new command is a new module there and one entry in :data:`COMMANDS`.
"""
from __future__ import annotations

from .cliutil import Parser, add_threads_option, run
from .commands import compat, estimate, freq, hq, model, refine, show, structure

# the command modules (identify.commands), in the order ``--help`` lists them
COMMANDS = (show, model, estimate, refine, structure, freq, compat, hq)


def build_parser() -> Parser:
    parser = Parser(prog="identify", description="Identify linear aircraft models from flight-test runs.")
    sub = parser.add_subparsers(title="commands")
    for command in COMMANDS:
        command.add_parser(sub)
    for p in sub.choices.values():
        add_threads_option(p)
    return parser


def main(argv=None) -> int:
    return run(build_parser(), argv)
