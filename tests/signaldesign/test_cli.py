"""``python -m signaldesign``: band, design, make, compare, plot, and one-line errors."""
import json

import pytest

from identify import load_profile
from signaldesign.cli import main
from signaldesign.signal import load_signals
from tests.helpers import one_error_line, run_cli


def cli(capsys, *args):
    """Run the command line in-process (subprocess start-up is slow on a shared machine):
    returns (status, stdout, stderr)."""
    status = main([str(a) for a in args])
    out = capsys.readouterr()
    return status, out.out, out.err


def one_line(capsys, args, *needles):
    status, _, err = cli(capsys, *args)
    # the progress bar redraws itself with carriage returns; the error is the one line after it
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("designing [")]
    assert status == 2 and len(lines) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def test_band_command_prints_the_band_and_modes(tmp_path, capsys):
    status, out, err = cli(capsys, "band", "--profile", "s61_hover_8state", "--input", "theta_s",
                           "--plot", tmp_path / "band.png")
    assert status == 0, err
    assert "required band for input theta_s" in out and "0.360 rad/s" in out
    assert "assumed noise" in out and (tmp_path / "band.png").stat().st_size > 1000


def test_make_compare_and_plot(tmp_path, capsys):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    status, out, err = cli(capsys, "make", "3211", "--width", "0.6", "--amplitude", "0.02", "--input", "theta_s",
                           "--out", a, "--csv", tmp_path / "a.csv")
    assert status == 0, err
    assert "half-power band" in out
    (sig,) = load_signals(a)
    assert sig.kind == "3211" and sig.dt == 0.6 and sig.levels.tolist() == [1, 1, 1, -1, -1, 1, -1]
    assert (tmp_path / "a.csv").read_text().splitlines()[2] == "time,theta_s"
    assert cli(capsys, "make", "doublet", "--width", "1.5", "--out", b)[0] == 0
    status, out, err = cli(capsys, "compare", "--profile", "s61_hover_8state", a, b)
    assert status == 0, err
    rows = [line for line in out.splitlines() if line.startswith(str(tmp_path))]
    assert len(rows) == 2 and rows[0].split()[2] == "1.000"  # the first file is the reference
    assert rows[1].split()[2] != "1.000"
    status, out, err = cli(capsys, "plot", a, b, "--out", tmp_path / "p.png", "--profile", "s61_hover_8state")
    assert status == 0, err
    assert (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"


def test_make_orthogonal_multisines_on_two_inputs(tmp_path, capsys):
    out, csv = tmp_path / "ms.json", tmp_path / "ms.csv"
    status, stdout, err = cli(capsys, "make", "multisine", "--input", "theta_s,theta_c", "--band", "0.5,5",
                              "--duration", "10", "--out", out, "--csv", csv)
    assert status == 0, err
    rpf = [float(line.rsplit(" ", 1)[1]) for line in stdout.splitlines() if "relative peak factor" in line]
    assert len(rpf) == 2 and max(rpf) <= 1.15
    a, b = load_signals(out)
    assert (a.input, b.input) == ("theta_s", "theta_c") and a.params["phases"] == "optimised"
    assert set(a.params["harmonics"]).isdisjoint(b.params["harmonics"])
    assert csv.read_text().splitlines()[2] == "time,theta_s,theta_c"
    status, stdout, err = cli(capsys, "make", "multisine", "--input", "theta_s,theta_c", "--profile", "bo105_70kt",
                              "--duration", "20", "--phases", "schroeder", "--out", out)
    assert status == 0 and "band from the profile" in stdout and "schroeder phases" in stdout, err
    one_line(capsys, ["make", "3211", "--width", "1", "--input", "theta_s,theta_c", "--out", out],
             "several inputs")


def test_design_command_writes_a_flyable_signal_within_the_limits(tmp_path, capsys):
    out = tmp_path / "opt.json"
    status, stdout, stderr = cli(capsys, "design", "--profile", "s61_hover_8state", "--input", "theta_s",
                                 "--duration", "3", "--record", "8", "--grid", "0.2", "--max-changes", "6",
                                 "--criterion", "nominal", "--jobs", "2", "--out", out, "--plot", tmp_path / "d.png")
    assert status == 0, stderr
    for label in ("doublet, best width", "3211, best width", "multisine", "PRTS", "optimised",
                  "equal peak response", "BINDS", "limits: the profile's [limits]", "certified D-efficiency"):
        assert label in stdout, label
    assert "designing [" in stderr  # the progress bar
    assert json.loads(out.read_text())["format"] == "pseudostep-signal/1"
    (sig,) = load_signals(out)
    assert set(sig.levels) <= {-1, 0, 1} and abs(sig.duration - 3) <= 1e-9
    assert (tmp_path / "d.png").read_bytes()[:4] == b"\x89PNG"
    status, stdout, _ = cli(capsys, "plot", out, "--out", tmp_path / "p.png", "--profile", "s61_hover_8state")
    assert status == 0 and "of the required band inside it" in stdout


def test_two_axis_design_reports_information_per_second(capsys):
    status, stdout, stderr = cli(capsys, "design", "--profile", "s61_hover_4dof", "--input", "theta_s,theta_c",
                                 "--duration", "2.8", "--record", "6", "--grid", "0.4", "--min-pulse", "0.4",
                                 "--criterion", "nominal")
    assert status == 0, stderr
    assert "information per second of flight" in stdout and "one run per axis" in stdout
    (cert,) = [line for line in stdout.splitlines() if line.startswith("certified D-efficiency")]
    value = float(cert.split()[3 if ">=" in cert else 2])
    assert 0 < value <= 1, cert


def _profile_with_limits(tmp_path, limits: str):
    text = (load_profile("s61_hover_4dof").to_toml().split("[limits]")[0] + "[limits]\n" + limits + "\n")
    path = tmp_path / "lim.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("args, needles", [
    (["band", "--profile", "no_such_profile", "--input", "theta_s"], ["no_such_profile", "no such profile"]),
    (["band", "--profile", "s61_hover_8state", "--input", "theta_x"], ["no input 'theta_x'"]),
    (["design", "--profile", "s61_hover_8state", "--input", "theta_s", "--duration", "0.1"],
     ["fewer than two"]),
    (["design", "--profile", "s61_hover_8state", "--input", "theta_s", "--dt", "0"], ["argument --dt", "must be positive"]),
    (["compare", "--profile", "s61_hover_8state", "x.json", "--dt", "0"], ["argument --dt", "must be positive"]),
    (["design", "--profile", "s61_hover_8state", "--input", "theta_s", "--jobs", "0"], ["argument --jobs"]),
    (["design", "--profile", "s61_hover_8state", "--input", "theta_s", "--duration", "3", "--record", "8",
      "--amplitude", "1"], ["infeasible", "within its limit"]),
    (["make", "3211", "--out", "x.json"], ["needs a pulse width"]),
    (["make", "multisine", "--band", "1", "--out", "x.json"], ["--band needs two frequencies"]),
])
def test_bad_input_gives_one_clear_error_line(tmp_path, capsys, monkeypatch, args, needles):
    monkeypatch.chdir(tmp_path)
    one_line(capsys, args, *needles)


def test_bad_profile_and_bad_signal_file(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\nstates = { q = "rad/s" }\ninputs = { e = "rad" }\noutputs = ["q"]\n[free]\nM_zz = 1\n')
    one_line(capsys, ["band", "--profile", bad, "--input", "e"], "bad.toml")
    junk = tmp_path / "junk.json"
    junk.write_text("{not json")
    one_line(capsys, ["compare", "--profile", "s61_hover_8state", junk], "junk.json")
    # and through the real entry point, as a user meets it
    one_error_line(run_cli("signaldesign", "compare", "--profile", "s61_hover_8state", junk), "junk.json")


@pytest.mark.parametrize("limits, needles", [
    ("zz = 1.0", ["[limits] zz: not an output"]),
    ("theta = 0.0", ["[limits] theta = 0 must be positive"]),
    ("theta = -0.1", ["[limits] theta = -0.1 must be positive"]),
])
def test_bad_limits_give_one_line_naming_them(tmp_path, capsys, limits, needles):
    one_line(capsys, ["design", "--profile", _profile_with_limits(tmp_path, limits), "--input", "theta_s"],
             "lim.toml", *needles)
