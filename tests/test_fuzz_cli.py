"""Fuzz the command lines: malformed files and arguments give one line on stderr and exit status 2,
never a traceback (identify, signaldesign and cueing, called in-process through ``main(argv)``).

Files: random bytes, text that looks like a run CSV (channel names, numbers, NaN, missing cells,
a BOM, too few rows), random JSON, TOML-like text, a truncated MATLAB header. Arguments: numeric
options given values no command may accept (0, negatives, NaN, inf, words). Every generated case is
invalid by construction (too few samples for any estimator, no valid signal or profile), so the
only acceptable outcome is the one-line refusal. Examples are few and there is no deadline: a
handful of cases per command cover the parsers, and the suite must stay fast.
"""
import contextlib
import io
import json
import string
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cueing.cli import main as cueing_main
from identify.cli import main as identify_main
from signaldesign.cli import main as signaldesign_main

SETTINGS = settings(max_examples=25, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
CHANNELS = ["time", "t", "u", "v", "p", "q", "theta", "phi", "theta_s", "theta_c", "q_dot", "x", ""]
CELLS = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=32).map(repr),
                  st.sampled_from(["", "nan", "inf", "-", "1e400", "abc", "0x1", "1,2", '"3"']))
BAD_NUMBERS = ["0", "-1", "nan", "inf", "-inf", "abc", "", "1e400"]
ZERO_IS_VALID = {"--skill"}


@st.composite
def csv_text(draw):
    """A run-like CSV with at most 5 rows: never enough samples for an estimate."""
    header = draw(st.lists(st.sampled_from(CHANNELS), min_size=1, max_size=8))
    rows = draw(st.lists(st.lists(CELLS, min_size=0, max_size=len(header) + 1), max_size=5))
    text = "\n".join([",".join(header)] + [",".join(r) for r in rows])
    prefix = draw(st.sampled_from(["", "\ufeff", "# meta: x\n", "#\n"]))
    return (prefix + text).encode("utf-8")


JSON_VALUES = st.recursive(st.none() | st.booleans() | st.floats(allow_nan=False) | st.text(max_size=8),
                           lambda inner: st.lists(inner, max_size=4)
                           | st.dictionaries(st.sampled_from(["kind", "input", "dt", "levels", "signals",
                                                              "format", "amplitude", "delay", "x"]),
                                             inner, max_size=5), max_leaves=12)
TOML_LINES = st.lists(st.one_of(st.sampled_from(["name = 'x'", "[free]", "[fixed]", "states = { u = 'm/s' }",
                                                 "inputs = { d = 'rad' }", "outputs = ['u']", "X_u = 1e999",
                                                 "X_d = 'a'", "[output_defs]", "= =", "[[x]]"]),
                                st.text(alphabet=string.printable, max_size=20)), max_size=8)
FILES = st.one_of(
    st.binary(max_size=200),
    csv_text(),
    JSON_VALUES.map(lambda v: json.dumps(v).encode()),
    TOML_LINES.map(lambda lines: "\n".join(lines).encode()),
    st.binary(max_size=60).map(lambda b: b"MATLAB 7.3 MAT-file, Platform: GLNXA64\x00" + b),
    st.just(b""),
)


def call(main, argv) -> tuple[int, str]:
    """Run ``main(argv)`` in-process; (exit status, stderr). An exception escapes as a test failure."""
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            code = main([str(a) for a in argv])
        except SystemExit as exc:  # argparse
            code = exc.code
    return code, err.getvalue()


def assert_one_line_refusal(main, argv):
    code, err = call(main, argv)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, (argv, code, err)
    assert len(lines) == 1 and "Traceback" not in err, (argv, err)


def _file(folder: Path, name: str, data: bytes) -> Path:
    path = folder / name
    path.write_bytes(data)
    return path


# (main, argv builder from a folder and the malformed file's path)
FILE_COMMANDS = {
    "identify model": (identify_main, lambda d, f: ["model", f]),
    "identify estimate ls": (identify_main, lambda d, f: ["estimate", f, "--profile", "s61_hover_8state",
                                                          "--method", "ls", "--out", d / "o"]),
    "identify estimate ml": (identify_main, lambda d, f: ["estimate", f, "--profile", "s61_hover_8state",
                                                          "--method", "ml", "--out", d / "o"]),
    "identify estimate bad profile": (identify_main, lambda d, f: ["estimate", f, "--profile", f,
                                                                   "--out", d / "o"]),
    "identify refine": (identify_main, lambda d, f: ["refine", f, "--profile", "s61_hover_8state",
                                                     "--out", d / "o"]),
    "identify structure": (identify_main, lambda d, f: ["structure", f, "--profile", "s61_hover_8state",
                                                        "--out", d / "o"]),
    "signaldesign band": (signaldesign_main, lambda d, f: ["band", "--profile", f, "--input", "theta_s"]),
    "signaldesign compare": (signaldesign_main, lambda d, f: ["compare", "--profile", "s61_hover_8state", f]),
    "signaldesign plot": (signaldesign_main, lambda d, f: ["plot", f, "--out", d / "s.png"]),
    "cueing recover": (cueing_main, lambda d, f: ["recover", f, "--out", d / "r.csv"]),
    "cueing fly": (cueing_main, lambda d, f: ["fly", "--signal", f, "--source", "pilot", "--headless",
                                              "--fast", "--out", d / "r.csv"]),
}


@pytest.mark.parametrize("command", sorted(FILE_COMMANDS))
@SETTINGS
@given(data=FILES, suffix=st.sampled_from([".csv", ".mat", ".json", ".toml", ".frames.csv", ""]))
def test_malformed_files_are_refused_in_one_line(command, data, suffix):
    main, argv = FILE_COMMANDS[command]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        assert_one_line_refusal(main, argv(folder, _file(folder, "input" + suffix, data)))


# (main, argv with a {} where the bad value goes)
NUMERIC_OPTIONS = [
    (identify_main, ["estimate", "RUN", "--profile", "s61_hover_8state", "--out", "OUT", "--smooth", "{}"]),
    (identify_main, ["estimate", "RUN", "--profile", "s61_hover_8state", "--out", "OUT", "--diff-cutoff", "{}"]),
    (identify_main, ["estimate", "RUN", "--profile", "s61_hover_8state", "--out", "OUT", "--max-iter", "{}"]),
    (identify_main, ["estimate", "RUN", "--profile", "s61_hover_8state", "--out", "OUT", "--threads", "{}"]),
    (identify_main, ["refine", "RUN", "--profile", "s61_hover_8state", "--out", "OUT", "--alpha", "{}"]),
    (identify_main, ["refine", "RUN", "--profile", "s61_hover_8state", "--out", "OUT", "--max-steps", "{}"]),
    (identify_main, ["structure", "RUN", "--profile", "s61_hover_8state", "--out", "OUT", "--tolerance", "{}"]),
    (signaldesign_main, ["band", "--profile", "s61_hover_8state", "--input", "theta_s", "--level", "{}"]),
    (signaldesign_main, ["design", "--profile", "s61_hover_8state", "--input", "theta_s", "--dt", "{}"]),
    (signaldesign_main, ["design", "--profile", "s61_hover_8state", "--input", "theta_s", "--duration", "{}"]),
    (signaldesign_main, ["design", "--profile", "s61_hover_8state", "--input", "theta_s", "--amplitude", "{}"]),
    (signaldesign_main, ["design", "--profile", "s61_hover_8state", "--input", "theta_s", "--record", "{}"]),
    (signaldesign_main, ["make", "3211", "--width", "{}", "--out", "OUT.json"]),
    (signaldesign_main, ["make", "multisine", "--dt", "{}", "--out", "OUT.json"]),
    (signaldesign_main, ["make", "3211", "--width", "0.5", "--amplitude", "{}", "--out", "OUT.json"]),
    (cueing_main, ["fly", "--signal", "SIG", "--source", "pilot", "--headless", "--fast", "--out", "OUT.csv",
                   "--rate", "{}"]),
    (cueing_main, ["fly", "--signal", "SIG", "--source", "pilot", "--headless", "--fast", "--out", "OUT.csv",
                   "--skill", "{}"]),
]


@pytest.fixture(scope="module")
def valid_inputs(tmp_path_factory, s61):
    """A valid run (S 61, 3 s at 20 Hz) and a valid signal, so that only the bad value is at fault."""
    import numpy as np

    from identify import simulate_run
    from signaldesign.cli import main as make
    folder = tmp_path_factory.mktemp("valid")
    t = np.arange(61) * 0.05
    u = np.zeros((len(t), 2))
    u[5:20, 0], u[20:35, 1] = 0.02, -0.02
    run = simulate_run(s61, t, u, noise_fraction=0.02, seed=1).to_csv(folder / "run.csv")
    sig = folder / "sig.json"
    assert call(make, ["make", "3211", "--width", "0.5", "--out", sig])[0] == 0
    return {"RUN": str(run), "SIG": str(sig), "folder": folder}


@pytest.mark.parametrize("case", range(len(NUMERIC_OPTIONS)))
@SETTINGS
@given(value=st.sampled_from(BAD_NUMBERS))
def test_bad_numeric_options_are_refused_in_one_line(valid_inputs, case, value):
    main, template = NUMERIC_OPTIONS[case]
    if value == "0" and template[-2] in ZERO_IS_VALID:
        value = "-1"
    folder = valid_inputs["folder"]
    argv = [value if a == "{}" else valid_inputs.get(a, a) for a in template]
    argv = [str(folder / a) if a.startswith("OUT") else a for a in argv]
    assert_one_line_refusal(main, argv)


@SETTINGS
@given(out=st.sampled_from(["RUN", "RUN/sub", "/dev/null/x", "/proc/version", ""]),
       command=st.sampled_from(["estimate", "refine"]))
def test_unwritable_out_is_refused_before_any_work(valid_inputs, out, command):
    """A file where the output folder should be (or under it): refused at once, nothing computed
    (the run is valid, so a check after the fit would show its progress lines on stderr)."""
    out = out.replace("RUN", valid_inputs["RUN"])
    assert_one_line_refusal(identify_main, [command, valid_inputs["RUN"], "--profile", "s61_hover_8state",
                                            "--out", out])
