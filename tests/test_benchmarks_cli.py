"""The benchmark scripts' command lines, without running any benchmark: ``--help`` of every script in
benchmarks/ exits 0 with its usage and nothing before it, the parser's description is the script's
docstring (what it measures), and the Makefile's ``BENCH_ARGS_<script>`` / ``BENCH_ALWAYS_<script>``
arguments (and none: the full size) parse with that script's own ``parser()``.

One child process does it all (one import of numpy and the packages for every script, and the
scripts' setting of BLAS threads and sys.path stays out of the test process)."""
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
BENCHMARKS = ROOT / "benchmarks"
SCRIPTS = sorted(p.stem for p in BENCHMARKS.glob("[!_]*.py"))

# argv: the benchmarks folder, then {script: [argument strings to parse]}; prints {script: report}
CHILD = r"""
import contextlib, io, json, runpy, shlex, sys
folder, cases = sys.argv[1], json.loads(sys.argv[2])
sys.path.insert(0, folder)
report = {}
for name, arg_lines in cases.items():
    path = f"{folder}/{name}.py"
    print(f"--help of {path}", file=sys.stderr, flush=True)  # the last line says which one hung
    out, code = io.StringIO(), "returned: --help ran the script"
    sys.argv = [path, "--help"]
    try:
        with contextlib.redirect_stdout(out):
            runpy.run_path(path, run_name="__main__")
    except SystemExit as exc:
        code = exc.code
    except BaseException as exc:
        code = f"raised {exc!r}"
    names = runpy.run_path(path, run_name="benchmark_cli_check")
    ap = names["parser"]() if callable(names.get("parser")) else None
    parsed = {}
    for line in arg_lines if ap else []:
        try:
            parsed[line] = repr(vars(ap.parse_args(shlex.split(line))))
        except SystemExit as exc:
            parsed[line] = f"error (exit {exc.code})"
    report[name] = {"code": code, "help": out.getvalue(), "parser": ap is not None,
                    "description_is_doc": ap is not None and ap.description == names["__doc__"], "parsed": parsed}
print(json.dumps(report))
"""


def makefile_arguments() -> dict[str, list[str]]:
    """Per script, the argument lines make benchmarks passes: reduced (ARGS + ALWAYS) and full (ALWAYS)."""
    found: dict[str, dict[str, str]] = {}
    for kind, name, value in re.findall(r"^BENCH_(ARGS|ALWAYS)_(\w+)\s*:?=\s*(.*)$",
                                        (ROOT / "Makefile").read_text(), re.M):
        found.setdefault(name, {})[kind] = value.strip()
    return {name: [f"{v.get('ARGS', '')} {v.get('ALWAYS', '')}".strip(), v.get("ALWAYS", "")]
            for name, v in found.items()}


@pytest.fixture(scope="module")
def report():
    lines = makefile_arguments()
    cases = {name: sorted(set(lines.get(name, [""]))) for name in SCRIPTS}
    proc = subprocess.run([sys.executable, "-c", CHILD, str(BENCHMARKS), json.dumps(cases)], capture_output=True,
                          text=True, cwd=ROOT, timeout=300,
                          env={**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg",
                               "SDL_VIDEODRIVER": "dummy", "SDL_AUDIODRIVER": "dummy"})
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout)


def test_every_makefile_entry_names_a_script():
    assert set(makefile_arguments()) <= set(SCRIPTS), "BENCH_ARGS_/BENCH_ALWAYS_ entries without a script"


@pytest.mark.parametrize("name", SCRIPTS)
def test_help_exits_zero_before_any_work(report, name):
    r = report[name]
    assert r["code"] in (0, None), f"{name}.py --help: {r['code']}"
    assert r["help"].startswith("usage:"), f"{name}.py printed before its usage:\n{r['help'][:500]}"


@pytest.mark.parametrize("name", SCRIPTS)
def test_parser_describes_what_it_measures(report, name):
    assert report[name]["parser"], f"{name}.py has no parser() (benchmarks/_cli.py)"
    assert report[name]["description_is_doc"], f"{name}.py: the parser's description is not its docstring"


@pytest.mark.parametrize("name", SCRIPTS)
def test_makefile_arguments_parse(report, name):
    bad = {line: got for line, got in report[name]["parsed"].items() if got.startswith("error")}
    assert not bad, f"{name}.py does not parse make benchmarks' arguments: {bad}"
