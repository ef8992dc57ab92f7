"""The commands the pipeline room brought: ``identify show``, the reader behind every command,
handling qualities by aircraft class, and figures that are not determined said as such."""
import json

import numpy as np
import pytest

from identify.cli import main
from tests.helpers import ROOT

EXAMPLES = ROOT / "examples"
MAP = EXAMPLES / "channel_map.json"


def cli(capsys, *args):
    capsys.readouterr()
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_show_says_units_as_read_and_used_ranges_trim_and_draws(tmp_path, capsys):
    code, out, err = cli(capsys, "show", EXAMPLES / "flight_lon.mat", "--channel-map", MAP, "--trim", "first:1s",
                         "--plot", tmp_path / "ch.png")
    assert code == 0, err
    rows = {line.split()[0]: line.split() for line in out.splitlines() if line.startswith("  ") and len(line.split()) > 5}
    assert rows["q"][1:3] == ["deg/s", "rad/s"] and rows["u"][1:4] == ["(none)", "SI", "(assumed)"]
    lo, hi = float(rows["q"][3]), float(rows["q"][4])  # rad/s, and the same range in deg/s as read
    assert out.count("..") >= 7 and f"{np.degrees(lo):.4g} .. {np.degrees(hi):.4g} deg/s" in out
    assert "50 Hz" in out and "trim: first:1s" in out and "derived: theta_c = (dar - dal)/2" in out
    assert "warning:" in out and (tmp_path / "ch.png").stat().st_size > 1000
    # the conversions said once per converted channel by the reader (every command's)
    assert sorted(line.split("'")[1] for line in err.splitlines() if "converted from" in line) == \
        ["dal", "dar", "p", "phi", "q", "theta", "theta_s"]


def test_every_frequency_command_reads_mat_with_the_channel_map(tmp_path, capsys):
    run, prof = EXAMPLES / "flight_lon.mat", EXAMPLES / "profile.toml"
    for args in (["freq", run, "--profile", prof], ["hq", run, "--profile", prof, "--n-freq", "40"],
                 ["loes", run, "--profile", prof, "--pair", "q/theta_s", "--n-freq", "40"]):
        code, _, err = cli(capsys, *args, "--channel-map", MAP, "--t-end", "12", "--out", tmp_path / args[0])
        assert code == 0, err
        assert "converted from deg/s to rad/s" in err


def test_read_runs_reads_mat_and_read_mat_takes_index_base(tmp_path):
    from scipy.io import savemat

    import identify
    from identify.data.matfile import read_mat, read_mat_runs

    runs = identify.read_runs([EXAMPLES / "flight_lon.mat"], channel_map=MAP)
    assert len(runs) == 1 and runs[0]["q"].max() < 0.1  # rad/s: converted
    t = np.arange(0, 2, 0.1)
    savemat(tmp_path / "m.mat", {"data": np.column_stack([np.full_like(t, 7.0), t, np.sin(t)])})
    one = read_mat(tmp_path / "m.mat", {"q": 3}, time=2, index_base=1)  # MATLAB numbering, column 1 unused
    assert np.allclose(one["q"], np.sin(t)) and np.allclose(one.time, t)
    assert np.allclose(read_mat_runs(tmp_path / "m.mat", {"q": 2}, time=1, index_base=0)[0]["q"], np.sin(t))


def test_a_map_with_columns_and_no_channels_reads_a_headerless_file(tmp_path, capsys):
    (tmp_path / "h.asc").write_text("".join(f"{k * 0.1:.1f} {k} {2 * k}\n" for k in range(20)))
    code, out, err = cli(capsys, "show", tmp_path / "h.asc", "--channel-map",
                         '{"columns": ["time", "q", "theta"], "units": {"q": "deg/s"}}')
    assert code == 0, err
    assert "channel 'q' converted from deg/s to rad/s" in err and "theta" in out


@pytest.mark.parametrize("profile, args, graded, category", [
    ("navion_cruise_long", [], False, "A"),  # a fixed wing (delta_e): said as guessed, never on the hover chart
    ("navion_cruise_long", ["--phase", "cruise"], False, "B"),
    ("s61_hover_8state", [], True, "A"),
    ("s61_hover_8state", ["--aircraft-class", "rotorcraft", "--phase", "forward"], False, "A"),
])
def test_hq_grades_ads33_only_for_a_rotorcraft_in_hover(tmp_path, capsys, profile, args, graded, category):
    code, out, err = cli(capsys, "hq", "--profile", profile, *args, "--out", tmp_path)
    assert code == 0, err
    assert ("ADS-33 level not graded" not in out) == graded
    assert (tmp_path / "hq_pitch.png").exists() == graded
    assert f"MIL-STD-1797A category {category}" in out and f"(category {category})" in out
    assert ("guessed from the controls" in out) == (not args)  # neither class nor phase given


def test_hq_refuses_a_phase_of_another_class(tmp_path, capsys):
    code, _, err = cli(capsys, "hq", "--profile", "navion_cruise_long", "--aircraft-class", "fixed-wing",
                       "--phase", "hover", "--out", tmp_path)
    assert code == 2 and "not a fixed-wing's" in err and len(err.strip().splitlines()) == 1


def test_loes_figures_at_a_bound_or_below_their_error_are_not_determined():
    from identify.estimators.frequency.loes import fit_transfer_function, short_period

    w = np.geomspace(0.5, 30, 120)
    s = 1j * w
    H = 5.0 * (s + 1.5) / (s ** 2 + 4.2 * s + 9.0)  # no delay: the fit's delay ends at its bound 0
    sp = short_period(fit_transfer_function(w, H, None, n_num=1, n_den=2))
    text = "\n".join(sp.lines() + [sp.fit.summary()])
    assert "tau_e at its bound 0 (not determined" in text and "e^(-0 s)" in text  # no 1e-21 of optimiser residue
    assert "tau                  0  not determined (at its bound 0)" in text
    assert sp.level == 1  # the delay graded on its upper limit, far inside Level 1
    # a delay the data cannot tell (standard error larger than the value): not determined, no level
    sp.fit.theta[-1], sp.fit.std[-1], sp.fit.tau, sp.tau_e, sp.std["tau_e"] = 0.079, 1e3, 0.079, 0.079, 1e3
    sp.fit.at_bound.clear()
    assert "tau_e not determined (standard error 1e+03 larger than the value)" in sp.lines()[0]


def test_time_history_plot_draws_the_inputs(tmp_path):
    from matplotlib.image import imread

    from identify import Job
    from identify.estimators.plots import plot_time_histories

    est = Job([EXAMPLES / "run_lon.csv"], EXAMPLES / "profile.toml", method="ls").estimate()
    bare = imread(plot_time_histories(est.result, tmp_path / "a.png", 0))
    with_inputs = imread(plot_time_histories(est.result, tmp_path / "b.png", 0, est.runs[0]))
    assert with_inputs.shape[0] > bare.shape[0]  # one panel more: the inputs


def test_numerical_failure_is_one_line_not_an_input_error(tmp_path, capsys, monkeypatch):
    from identify.estimators.frequency import response_fit

    def fail(*a, **k):
        raise np.linalg.LinAlgError("SVD did not converge in Linear Least Squares")

    monkeypatch.setattr(response_fit, "fit_frequency_responses", fail)
    code, _, err = cli(capsys, "estimate", "--method", "fr", "--profile", EXAMPLES / "profile.toml",
                       EXAMPLES / "run_lon.csv", "--out", tmp_path)
    assert code == 2 and len(err.strip().splitlines()) == 2  # the held-inputs warning, then the error
    assert "numerical failure, not an input error: SVD did not converge" in err.strip().splitlines()[-1]
