"""``python -m cueing``: fly signals on the two-needle display, practise, and run the demo."""
from __future__ import annotations

from identify.cliutil import Parser, run


def cmd_demo(args) -> int:
    from .demo import run_demo
    report = run_demo(args.out, args.profile)
    print(f"demo written to {report.parent}/ (open {report})")
    return 0


def build_parser() -> Parser:
    parser = Parser(prog="cueing", description="Two-needle pilot cueing display for flight-test inputs.")
    sub = parser.add_subparsers(title="commands")
    p = sub.add_parser("demo", help="run the whole pipeline on the default profile, without a window")
    p.add_argument("--out", default="demo-output", help="output folder (default: demo-output)")
    p.add_argument("--profile", default="s61_hover_8state", help="profile path or bundled name")
    p.set_defaults(func=cmd_demo)
    return parser


def main(argv=None) -> int:
    return run(build_parser(), argv)
