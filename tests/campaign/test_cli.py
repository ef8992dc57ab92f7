"""``python -m campaign``: the subcommand table and the error contract (one line, exit status 2)."""
from campaign.cli import COMMANDS, build_parser
from tests.helpers import one_error_line, run_cli


def test_every_command_of_the_table_is_a_subcommand():
    proc = run_cli("campaign", "--help")
    assert proc.returncode == 0 and all(name in proc.stdout for name in COMMANDS)
    assert build_parser().parse_args(["demo", "--quick"]).quick


def test_demo_with_an_unknown_profile_is_one_error_line(tmp_path):
    proc = run_cli("campaign", "demo", "--profile", "no_such_profile", "--out", tmp_path / "demo")
    one_error_line(proc, "no_such_profile")
