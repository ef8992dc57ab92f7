"""``python -m campaign``: whole pipelines and test campaigns from the command line.

Each subcommand is one entry of :data:`COMMANDS` (name -> function adding its parser); its
``func`` runs it and returns the exit status.
"""
from __future__ import annotations

from identify.cliutil import Parser, add_threads_option, output_dir, run

from . import commands


def cmd_demo(args) -> int:
    from .demo import DEFAULT_PROFILE, run_demo  # the pipeline's libraries load only when it runs
    report = run_demo(args.out, args.profile or DEFAULT_PROFILE, quick=args.quick, frames=args.frames)
    print(f"demo written to {report.parent}/ (open {report})")
    return 0


def add_demo(sub) -> None:
    p = sub.add_parser("demo", help="run the whole pipeline on the default profile, without a window")
    p.add_argument("--out", default="demo-output", type=output_dir, help="output folder (default: demo-output)")
    p.add_argument("--profile", help="profile path or bundled name (default: s61_hover_8state)")
    p.add_argument("--quick", action="store_true", help="reduced size (shorter runs, shorter search)")
    p.add_argument("--frames", action="store_true",
                   help="keep the display's frames (one a second) in display_frames_<run>/ (default: display.png only)")
    p.set_defaults(func=cmd_demo)


COMMANDS = {"demo": add_demo}  # subcommand -> adds its parser
COMMANDS.update(design=commands.add_design, identify=commands.add_identify,  # the test campaign
                stitch=commands.add_stitch, report=commands.add_report, synthetic=commands.add_synthetic)


def build_parser() -> Parser:
    parser = Parser(prog="campaign", description="Whole pipelines and test campaigns: design, fly, identify, "
                                                 "refine, report.")
    sub = parser.add_subparsers(title="commands")
    for add in COMMANDS.values():
        add(sub)
    for p in sub.choices.values():
        add_threads_option(p)
    return parser


def main(argv=None) -> int:
    return run(build_parser(), argv)
