"""``python -m identify estimate``: files written, progress shown, bad input as one line."""
import json
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.io import savemat

from identify import Run, load_profile, simulate_run
from identify.cli import main
from tests.helpers import one_error_line, run_cli

DT = 0.01
PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def runs(tmp_path_factory, s61):
    """Two noisy 10 s S 61 runs as CSV files (longitudinal and lateral cyclic)."""
    folder = tmp_path_factory.mktemp("runs")
    t = np.arange(1001) * DT
    paths = []
    for k, (a, b) in enumerate(((0.02, 0.005), (0.005, 0.02))):
        u = np.zeros((len(t), 2))
        u[100:300, 0], u[300:500, 0] = a, -a
        u[500:650, 1], u[650:800, 1] = b, -b
        run = simulate_run(s61, t, u, seed=k, noise_fraction=0.01)
        paths.append(run.to_csv(folder / f"run{k + 1}.csv"))
    return paths


def _in_process(argv, capsys):
    """Run the command line in this process; returns an object like a CompletedProcess."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse usage errors
        code = exc.code
    out = capsys.readouterr()
    return SimpleNamespace(returncode=code, stdout=out.out, stderr=out.err)


def test_ls_writes_result_json_profile_and_plots(runs, tmp_path, s61):
    out = tmp_path / "ls"
    proc = run_cli("identify", "estimate", "--profile", "s61_hover_8state", "--method", "ls", runs[0],
                   "--out", out, "--plots")
    assert proc.returncode == 0, proc.stderr
    assert "LS identification" in proc.stdout and "M_theta_R" in proc.stdout and "Theil" in proc.stdout
    result = json.loads((out / "result.json").read_text())
    assert set(result["parameters"]) == set(s61.names)
    for name, entry in result["parameters"].items():
        assert np.isfinite(entry["value"]) and entry["std"] > 0, name
    assert result["parameters"]["L_phi_R"]["value"] == pytest.approx(14.5, rel=0.05)
    assert set(result["fit"]["q"]) == {"rms", "theil"} and len(result["eigenvalues"]) == 6
    identified = load_profile(out / "identified_profile.toml")
    assert identified.free["M_q"] == pytest.approx(result["parameters"]["M_q"]["value"], rel=1e-12)
    for png in ("time_history_run1.png", "residuals.png"):
        data = (out / png).read_bytes()
        assert data.startswith(PNG) and len(data) > 10_000, png


def test_iv_on_two_runs_with_smoothing_and_slicing_shows_progress(runs, tmp_path, capsys):
    out = tmp_path / "iv"
    proc = _in_process(["estimate", "--profile", "s61_hover_8state", "--method", "iv", *runs, "--out", out,
                        "--smooth", "10", "--t-start", "0.5", "--t-end", "9.5"], capsys)
    assert proc.returncode == 0, proc.stderr
    assert not list(out.glob("*.png")) and "(plots: add --plots)" in proc.stdout  # plots on request only
    proc = _in_process(["estimate", "--profile", "s61_hover_8state", "--method", "iv", *runs, "--out", out,
                        "--smooth", "10", "--t-start", "0.5", "--t-end", "9.5", "--plots"], capsys)
    assert "IV iteration 1: max rel. change" in proc.stderr
    result = json.loads((out / "result.json").read_text())
    assert result["method"] == "iv" and len(result["runs"]) == 2 and result["info"]["converged"]
    steps = result["info"]["processing"]
    assert [s["step"] for s in steps[1]] == ["smooth", "slice"] and steps[1][0]["cutoff_hz"] == 10.0
    assert {p.name for p in out.glob("*.png")} == {"time_history_run1.png", "time_history_run2.png",
                                                   "residuals.png"}


def test_mat_runs_with_a_channel_map(runs, tmp_path, capsys, s61):
    from identify import read_run
    run = read_run(runs[0])
    names = ["time"] + s61.profile.channels + [s + "_dot" for s in s61.profile.state_names]
    savemat(tmp_path / "flight.mat", {"Z": np.column_stack([run[n] for n in names])})
    cmap = json.dumps({"channels": {n: i for i, n in enumerate(names) if n != "time"}, "time": 0})
    proc = _in_process(["estimate", "--profile", "s61_hover_8state", "--method", "ls", tmp_path / "flight.mat",
                        "--channel-map", cmap, "--out", tmp_path / "out"], capsys)
    assert proc.returncode == 0, proc.stderr
    from_mat = json.loads((tmp_path / "out" / "result.json").read_text())["parameters"]
    _in_process(["estimate", "--profile", "s61_hover_8state", "--method", "ls", runs[0], "--out",
                 tmp_path / "csv"], capsys)
    from_csv = json.loads((tmp_path / "csv" / "result.json").read_text())["parameters"]
    for name in from_csv:
        assert from_mat[name]["value"] == pytest.approx(from_csv[name]["value"], rel=1e-9)


def test_bad_input_gives_one_line_and_status_2(runs, tmp_path, capsys, s61):
    base = ["estimate", "--profile", "s61_hover_8state", "--out", tmp_path / "x"]
    one_error_line(_in_process(base + [tmp_path / "nope.csv"], capsys), "nope.csv")
    one_error_line(_in_process(base + ["--smooth", "80", runs[0]], capsys), "Nyquist", "80")
    one_error_line(_in_process(base + ["--method", "xx", runs[0]], capsys), "xx")
    one_error_line(_in_process(["estimate", "--profile", "no_such_profile", "--out", tmp_path, runs[0]], capsys),
                   "no_such_profile")
    one_error_line(_in_process(base + ["--t-start", "50", runs[0]], capsys), "fewer than two samples")
    one_error_line(_in_process(base + ["--channel-map", "{bad", tmp_path / "f.mat"], capsys), "JSON")
    # a state not measured: equation error says why it needs it
    t = np.arange(101) * DT
    partial = Run(t, {"theta_s": np.zeros(101), "theta_c": np.zeros(101), "q": np.sin(t)}).to_csv(
        tmp_path / "partial.csv")
    one_error_line(_in_process(base + ["--method", "ls", partial], capsys), "partial.csv", "every state", "theta_R")
    # and through a real subprocess: no traceback, exit status 2
    one_error_line(run_cli("identify", "estimate", "--profile", "s61_hover_8state", "--out", tmp_path / "y",
                           tmp_path / "nope.csv"), "nope.csv")


def test_unwritable_outputs_and_bad_options_give_one_line(tmp_path):
    """Writing to a folder that does not exist, or nonsense options: one line, exit 2, no traceback."""
    from tests.helpers import one_error_line, run_cli

    one_error_line(run_cli("identify", "model", "s61_hover_8state", "--reduce", "theta_R",
                           "--save-reduced", tmp_path / "no" / "dir" / "r.toml"), "r.toml")
    one_error_line(run_cli("identify", "model", "s61_hover_4dof", "--reduce", "u,v,p,q,theta,phi"),
                   "no state would be left")
    one_error_line(run_cli("identify", "model", "s61_hover_8state", "--reduce", "theta_R,theta_R"), "twice")
    one_error_line(run_cli("signaldesign", "make", "doublet", "--width", "1", "--input", "theta_s",
                           "--out", tmp_path / "no" / "dir" / "s.json"), "s.json")
