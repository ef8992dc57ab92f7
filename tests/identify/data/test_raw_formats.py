"""Raw files as flight-test tools write them (the audit of docs/real_data.md's outcome table): each
layout reads to the values the plain file gives, what was guessed or repaired said on stderr and
recorded in the run's metadata, or the file is refused in one line naming the fix."""
import numpy as np
import pytest
from scipy.io import savemat

from identify import RunError
from identify.data.ingest import ReadOptions
from identify.data.io import load_channel_map, read_file_runs, read_run_file
from identify.data.provenance import provenance
from tests.identify.data.test_ingest import CHANNELS, PROFILE, truth_run  # noqa: F401

DEG = np.pi / 180


def _table(run, n=60):
    """time, q in deg/s, theta in deg (the first n samples)."""
    return run.time[:n], np.degrees(run["q"][:n]), np.degrees(run["theta"][:n])


def _check(run, truth, n=60):
    np.testing.assert_allclose(run["q"], truth["q"][:len(run)], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(run["theta"], truth["theta"][:len(run)], rtol=1e-6, atol=1e-9)


def test_european_csv_semicolons_and_decimal_comma(truth_run, tmp_path, capsys):
    t, q, th = _table(truth_run)
    rows = "\n".join(f"{a:.6f};{b:.9f};{c:.9f}".replace(".", ",") for a, b, c in zip(t, q, th))
    (tmp_path / "eu.csv").write_text("Zeit [s];q [deg/s];theta [deg]\n" + rows + "\n")
    run = read_run_file(tmp_path / "eu.csv", {"time": "Zeit", "channels": {"q": "q", "theta": "theta"}})
    _check(run, truth_run)
    assert "decimal comma" in run.meta["notes"] and "decimal comma" in capsys.readouterr().err


def test_a_row_of_units_under_the_header(truth_run, tmp_path, capsys):
    t, q, th = _table(truth_run)
    rows = "\n".join(f"{a:.6f},{b:.9f},{c:.9f}" for a, b, c in zip(t, q, th))
    (tmp_path / "u.csv").write_text("time,q,theta\ns,deg/s,deg\n" + rows + "\n")
    run = read_run_file(tmp_path / "u.csv")
    _check(run, truth_run)
    assert "line 2 under the header read as the columns' units" in run.meta["notes"]
    assert "q from deg/s" in run.meta["converted_to_si"]
    (tmp_path / "bad.csv").write_text("time,q,theta\ns,deg/s,degs\n" + rows + "\n")
    with pytest.raises(RunError, match=r"line 2 \(units under the header\), column 'theta': unknown unit 'degs'"):
        read_run_file(tmp_path / "bad.csv")


def test_several_empty_columns_at_the_end_of_every_line(truth_run, tmp_path):
    t, q, th = _table(truth_run)
    rows = "\n".join(f"{a:.6f},{b:.9f},{c:.9f},," for a, b, c in zip(t, q, th))
    (tmp_path / "e.csv").write_text("time,q [deg/s],theta [deg],,\n" + rows + "\n")
    run = read_run_file(tmp_path / "e.csv")
    _check(run, truth_run)
    assert set(run.channels) == {"q", "theta"} and "2 empty column(s)" in run.meta["notes"]


@pytest.mark.parametrize("encoding, delim, needle", [("utf-16", "\t", "UTF-16"), ("cp1252", ",", "Windows-1252")])
def test_utf16_and_windows_1252_text(truth_run, tmp_path, encoding, delim, needle):
    t, q, th = _table(truth_run)
    rows = "\n".join(delim.join(f"{v:.9f}" for v in r) for r in zip(t, q, th))
    text = delim.join(["time", "q [°/s]", "theta [°]"]) + "\r\n" + rows.replace("\n", "\r\n") + "\r\n"
    (tmp_path / "x.csv").write_bytes(text.encode(encoding))
    run = read_run_file(tmp_path / "x.csv")
    _check(run, truth_run)
    assert needle in run.meta["notes"]
    (tmp_path / "bin.csv").write_bytes(b"time,q\n\x00\x81\x00")
    with pytest.raises(RunError, match="not a text"):
        read_run_file(tmp_path / "bin.csv")


def test_a_last_line_cut_short_is_left_out_and_said_a_short_line_inside_refused(truth_run, tmp_path, capsys):
    t, q, th = _table(truth_run)
    lines = ["time,q [deg/s],theta [deg]"] + [f"{a:.6f},{b:.9f},{c:.9f}" for a, b, c in zip(t, q, th)]
    text = "\n".join(lines)
    (tmp_path / "cut.csv").write_text(text[:text.rfind(",") - 2])  # the write stopped mid-line
    run = read_run_file(tmp_path / "cut.csv")
    assert len(run) == 59
    _check(run, truth_run)
    assert "line 61, the last, is cut short" in run.meta["notes"] and "cut short" in capsys.readouterr().err
    (tmp_path / "short.csv").write_text("\n".join(lines[:30] + [lines[30].rsplit(",", 1)[0]] + lines[31:]) + "\n")
    with pytest.raises(RunError, match="line 31: 2 values for 3 columns"):
        read_run_file(tmp_path / "short.csv")


@pytest.mark.parametrize("cut", ["0.12", "", "3"])
def test_a_last_value_cut_inside_is_left_out_and_said(truth_run, tmp_path, cut):
    """A logger writing a fixed format, stopped inside the last value (no line break at the end):
    the line has all its values, but its last one is shorter than the column ever is; read as a
    number it was a wrong sample."""
    t, q, th = _table(truth_run)
    text = "time,q [deg/s],theta [deg]\n" + "\n".join(f"{a:.3f},{b:.9f},{c:.9f}" for a, b, c in zip(t, q, th))
    path = tmp_path / "cut.csv"
    path.write_text(text[:text.rindex(",") + 1] + cut)
    run = read_run_file(path)
    assert len(run) == len(t) - 1
    _check(run, truth_run)
    assert f"ends in a value shorter than every line before it writes that column ('{cut}')" in run.meta["notes"]


def test_a_varying_written_width_or_a_line_break_at_the_end_is_no_cut(truth_run, tmp_path):
    t, q, th = _table(truth_run)
    general = "\n".join(f"{a:g},{b:g},{c:g}" for a, b, c in zip(t, q, th))  # %g: widths vary
    (tmp_path / "g.csv").write_text("time,q [deg/s],theta [deg]\n" + general)
    assert len(read_run_file(tmp_path / "g.csv")) == len(t)
    fixed = "\n".join(f"{a:.3f},{b:.6f},{c:.2f}" for a, b, c in zip(t, q, th))
    (tmp_path / "f.csv").write_text("time,q [deg/s],theta [deg]\n" + fixed[:-1] + "\n")  # ends in a break
    assert len(read_run_file(tmp_path / "f.csv")) == len(t)


def test_a_data_matrix_with_channels_in_rows_is_read_transposed_and_said(truth_run, tmp_path):
    Z = np.column_stack([truth_run.time, truth_run["q"], truth_run["theta"]])
    savemat(tmp_path / "rows.mat", {"rows": Z.T})  # 3 x N: one channel per row
    run = read_run_file(tmp_path / "rows.mat", {"time": 0, "channels": {"q": 1, "theta": 2}})
    _check(run, truth_run)
    assert "3 channels in rows" in run.meta["notes"] and "transposed" in run.meta["matrix"]


def test_time_in_milliseconds_undeclared_warns_with_the_fix(truth_run, tmp_path):
    t, q, th = _table(truth_run)
    rows = "\n".join(f"{a * 1000:.3f},{b:.9f},{c:.9f}" for a, b, c in zip(t, q, th))
    (tmp_path / "ms.csv").write_text("time,q [deg/s],theta [deg]\n" + rows + "\n")
    run = read_run_file(tmp_path / "ms.csv")
    assert "time step is 20 s" in run.meta["warnings"] and "a header 'time [ms]'" in run.meta["warnings"]
    (tmp_path / "ms2.csv").write_text("time [ms],q [deg/s],theta [deg]\n" + rows + "\n")
    assert "warnings" not in read_run_file(tmp_path / "ms2.csv").meta


def test_time_in_days_undeclared_warns_and_reads_when_declared(truth_run, tmp_path):
    """A MATLAB datenum (days) read as seconds makes 50 Hz look like 4 MHz: said, with the unit to declare."""
    t, q, th = _table(truth_run)
    rows = "\n".join(f"{739000 + a / 86400:.12f},{b:.9f},{c:.9f}" for a, b, c in zip(t, q, th))
    (tmp_path / "d.csv").write_text("time,q [deg/s],theta [deg]\n" + rows + "\n")
    warned = read_run_file(tmp_path / "d.csv").meta["warnings"]
    assert "too fast for a flight-test record" in warned and "a header 'time [day]'" in warned
    (tmp_path / "d2.csv").write_text("time [day],q [deg/s],theta [deg]\n" + rows + "\n")
    run = read_run_file(tmp_path / "d2.csv")
    assert "warnings" not in run.meta
    np.testing.assert_allclose(np.diff(run.time), np.diff(t), atol=1e-4)


def test_a_constant_channel_the_profile_uses_warns(truth_run, tmp_path):
    t, q, th = _table(truth_run)
    rows = "\n".join(f"{a:.6f},{b:.9f},2.5,0" for a, b in zip(t, q))
    (tmp_path / "dead.csv").write_text("time,q [deg/s],theta [deg],eta\n" + rows + "\n")
    run = read_run_file(tmp_path / "dead.csv", profile=PROFILE)
    assert "channel 'theta' is constant (0.0436332 in all 60 samples)" in run.meta["warnings"]
    # a control held at trim is how a run of another axis is flown, not a dead sensor
    assert "'eta' is constant" not in run.meta["warnings"]


@pytest.mark.parametrize("consistent", [False, True])
def test_degrees_found_by_kinematics_when_the_attitude_barely_moves(truth_run, tmp_path, consistent):
    """theta moves a twentieth of the truth run's motion, its noise half that motion's spread (the
    share of variance the rate explains is then about 0.8): q in deg/s read as rad/s is still
    found, and consistent units give no warning."""
    rng = np.random.default_rng(7)
    q = 0.05 * truth_run["q"]
    theta = 0.05 * truth_run["theta"]
    theta = theta + rng.normal(0, 0.5 * np.std(theta), theta.size)
    cols = np.column_stack([truth_run.time, q if consistent else np.degrees(q), theta])
    np.savetxt(tmp_path / "small.csv", cols, delimiter=",", fmt="%.12g", header="time,q,theta", comments="")
    run = read_run_file(tmp_path / "small.csv", profile=PROFILE)
    if consistent:
        assert "warnings" not in run.meta
    else:
        assert "channel 'q' looks like deg/s" in run.meta["warnings"]


def test_a_clock_coarser_than_the_step_is_rebuilt_as_the_uniform_grid_and_said(truth_run, tmp_path):
    """Time in single precision at a GPS-week offset (resolution 1/32 s at 50 Hz) or written with
    one decimal too few: the stamps repeat or alternate between steps; read as the uniform grid."""
    t = truth_run.time + 387654.0
    savemat(tmp_path / "gps.mat", {"t": t.astype(np.float32), "q": truth_run["q"], "theta": truth_run["theta"]})
    run = read_run_file(tmp_path / "gps.mat", {"channels": {"q": "q", "theta": "theta"}})
    np.testing.assert_allclose(run.time - run.time[0], truth_run.time, atol=1e-9)
    _check(run, truth_run)
    assert "single precision at 387670" in run.meta["time_rebuilt"]
    rows = "\n".join(f"{a:.1f},{b:.12g}" for a, b in zip(truth_run.time, truth_run["q"]))
    (tmp_path / "coarse.csv").write_text("time,q\n" + rows + "\n")
    run = read_run_file(tmp_path / "coarse.csv")
    np.testing.assert_allclose(run.time, truth_run.time, atol=1e-9)
    assert "written with 1 decimal(s)" in run.meta["time_rebuilt"] and "time stamps resolve only" in run.meta["notes"]
    # a real gap is no coarse clock: the stamps stray from the grid by far more than the resolution
    keep = np.r_[0:300, 320:len(truth_run)]
    rows = "\n".join(f"{a:.2f},{b:.12g}" for a, b in zip(truth_run.time[keep], truth_run["q"][keep]))
    (tmp_path / "gap.csv").write_text("time,q\n" + rows + "\n")
    assert len(read_file_runs(tmp_path / "gap.csv")) == 2


def test_a_cell_array_of_channels_is_named_with_the_fix(truth_run, tmp_path):
    cell = np.empty(2, dtype=object)
    cell[:] = [truth_run.time, truth_run["q"]]
    savemat(tmp_path / "cell.mat", {"c": cell})
    with pytest.raises(RunError, match=r"not read: c \(cell array of 2\): save the cell's vectors as variables"):
        read_run_file(tmp_path / "cell.mat", {"time": "c{1}", "channels": {"q": "c{2}"}})


def test_map_dt_in_seconds_agrees_with_a_time_column_in_milliseconds(truth_run, tmp_path):
    """The map's "dt" is in s; a time column declared in ms is compared after its conversion."""
    t, q, th = _table(truth_run)
    rows = "\n".join(f"{1000 * a:.3f},{b:.9f},{c:.9f}" for a, b, c in zip(t, q, th))
    (tmp_path / "ms.csv").write_text("time [ms],q [deg/s],theta [deg]\n" + rows + "\n")
    step = float(np.median(np.diff(t)))
    run = read_run_file(tmp_path / "ms.csv", {"dt": step})
    _check(run, truth_run)
    with pytest.raises(RunError, match="disagrees with the time column"):
        read_run_file(tmp_path / "ms.csv", {"dt": 2 * step})


def _rows_csv(path, t, q, th, fmt="{:.6f}"):
    rows = "\n".join(f"{fmt.format(a)},{b:.9g},{c:.9g}" for a, b, c in zip(t, q, th))
    path.write_text("time,q [deg/s],theta [deg]\n" + rows + "\n")
    return path


def test_declared_missing_value_markers_are_nan_then_the_nan_policy(truth_run, tmp_path, capsys):
    """-999 in the file is a missing sample when the map says so ("missing": number, list or per
    channel), in file units (before deg -> rad); the NaN policy then applies, said and recorded."""
    t, q, th = _table(truth_run)
    q, th = q.copy(), th.copy()
    q[[10, 30]], th[20] = -999.0, 99999.0
    path = _rows_csv(tmp_path / "m.csv", t, q, th)
    with pytest.raises(RunError, match=r"line 12, channel 'q': missing value \(marker -999 in the file\)"):
        read_run_file(path, {"channels": {"q": "q", "theta": "theta"}, "missing": [-999, 99999]})
    for missing in ([-999, 99999], {"q": -999, "theta": [99999]}):
        run = read_run_file(path, {"channels": {"q": "q", "theta": "theta"}, "missing": missing},
                            options=ReadOptions("interpolate"))
        assert len(run) == 60 and np.all(np.isfinite(run["q"]))
        np.testing.assert_allclose(run["q"][9:12], np.interp(t[9:12], t[[9, 11]], truth_run["q"][[9, 11]]))
        assert "'q': 2 x -999 (line 12, line 32)" in run.meta["missing_markers"]
        assert "'theta': 1 x 99999 (line 22)" in run.meta["missing_markers"]
        assert "warnings" not in run.meta
    assert "marker(s) read as missing" in capsys.readouterr().err
    run = read_file_runs(path, {"channels": {"q": "q", "theta": "theta"}, "missing": -999}, options=ReadOptions("drop"))
    assert "dropped_samples" in run[0].meta


def test_an_undeclared_marker_like_value_warns_with_the_count_and_the_fix(truth_run, tmp_path, capsys):
    t, q, th = _table(truth_run)
    q = q.copy()
    q[[5, 6, 40]] = -9999.0
    run = read_run_file(_rows_csv(tmp_path / "s.csv", t, q, th))
    assert "channel 'q': 3 value(s) exactly -9999 (line 7, line 8, line 42), far outside" in run.meta["warnings"]
    assert "\"missing\": -9999" in capsys.readouterr().err
    run = read_run_file(tmp_path / "s.csv", {"channels": {"q2": "2 * q", "theta": "theta"}})  # an operand's too
    assert "channel 'q': 3 value(s) exactly -9999" in run.meta["warnings"]
    # a value of the list within a channel's range is data: a pressure of 999 hPa among 990 .. 1010
    p = np.linspace(990.0, 1010.0, 60)
    p[17] = 999.0
    assert "warnings" not in read_run_file(_rows_csv(tmp_path / "p.csv", t, p, th)).meta


def test_markers_in_a_mat_file(truth_run, tmp_path):
    q = np.degrees(truth_run["q"]).copy()
    q[100] = -999.0
    savemat(tmp_path / "m.mat", {"t": truth_run.time, "q": q})
    run = read_run_file(tmp_path / "m.mat", {"channels": {"q": "q"}, "units": {"q": "deg/s"}})
    assert "channel 'q': 1 value(s) exactly -999 (sample 101)" in run.meta["warnings"]
    run = read_run_file(tmp_path / "m.mat", {"channels": {"q": "q"}, "units": {"q": "deg/s"}, "missing": -999},
                        options=ReadOptions("interpolate"))
    assert "'q': 1 x -999 (sample 101)" in run.meta["missing_markers"] and np.all(np.isfinite(run["q"]))
    with pytest.raises(RunError, match="'missing' must be a number"):
        load_channel_map('{"channels": {"q": "q"}, "missing": "-999"}')


@pytest.mark.parametrize("marker, shown", [(-32768.0, "-32768"), (1e30, "1e+30"),
                                           (float(np.float32(9.96921e36)), "9.96921e+36")])
def test_integer_extremes_and_fill_values_as_undeclared_markers_warn(truth_run, tmp_path, marker, shown):
    t, q, th = _table(truth_run)
    q = q.copy()
    q[9] = marker
    savemat(tmp_path / "f.mat", {"t": t, "q": q, "theta": th})
    run = read_run_file(tmp_path / "f.mat", {"channels": {"q": "q", "theta": "theta"}})
    assert f"channel 'q': 1 value(s) exactly {shown} (sample 10), far outside" in run.meta["warnings"]


def _two_rates(truth_run):
    """The truth run at 25 Hz for its first 4 s, at 50 Hz after."""
    keep = np.r_[0:200:2, 200:len(truth_run)]
    return truth_run.time[keep], np.degrees(truth_run["q"][keep]), np.degrees(truth_run["theta"][keep])


def test_a_sample_rate_changing_within_a_file_is_refused_once_naming_where_and_the_fix(truth_run, tmp_path):
    t, q, th = _two_rates(truth_run)
    path = _rows_csv(tmp_path / "r.csv", t, q, th)
    with pytest.raises(RunError, match=r"the sample rate changes at line 102 \(t = 4 s\): 25 Hz \(step 0.04 s\) "
                                       r"up to it, 50 Hz \(step 0.02 s\) after it; .*resample the file to one rate, "
                                       r"or read one part, before or after t = 4 s, with --t-start/--t-end"):
        read_file_runs(path)
    savemat(tmp_path / "r.mat", {"t": t, "q": q, "theta": th})
    with pytest.raises(RunError, match=r"changes at sample 101 \(t = 4 s\): 25 Hz"):
        read_file_runs(tmp_path / "r.mat")
    # the window of one rate reads that part, said
    run = read_run_file(path, options=ReadOptions(t_start=5.0))
    assert run.time[0] == pytest.approx(5.0) and run.dt == pytest.approx(0.02)
    assert "outside the window" in run.meta["rate_change_outside_window"]
    # single gaps and lone samples between gaps stay gaps, not rate changes
    keep = np.r_[0:300, 305, 310:len(truth_run)]
    gapped = _rows_csv(tmp_path / "g.csv", truth_run.time[keep], truth_run["q"][keep], truth_run["theta"][keep])
    assert len(read_file_runs(gapped)) == 2


def _clock(seconds: float) -> str:
    h, rest = divmod(seconds % 86400, 3600)
    return f"{int(h):02d}:{int(rest // 60):02d}:{rest % 60:06.3f}"


@pytest.mark.parametrize("form", ["clock", "iso", "dated_blank", "midnight"])
def test_clock_time_stamps_are_read_as_seconds_from_the_first_sample_and_said(truth_run, tmp_path, form):
    t, q, th = _table(truth_run)
    start = 86400 - 0.5 if form == "midnight" else 12 * 3600 + 34 * 60 + 56.02
    stamps = [_clock(start + a) for a in t]
    if form == "iso":
        stamps = [f"2026-11-26T{s}" for s in stamps]
    if form == "dated_blank":  # whitespace-separated, the date and the clock two words of one cell
        rows = "\n".join(f"2026-11-26 {s} {b:.9f} {c:.9f}" for s, b, c in zip(stamps, q, th))
        (tmp_path / "c.txt").write_text("time q theta\n" + rows + "\n")
        run = read_run_file(tmp_path / "c.txt", {"channels": {"q": "q", "theta": "theta"},
                                                 "units": {"q": "deg/s", "theta": "deg"}})
    else:
        rows = "\n".join(f"{s},{b:.9f},{c:.9f}" for s, b, c in zip(stamps, q, th))
        (tmp_path / "c.csv").write_text("time,q [deg/s],theta [deg]\n" + rows + "\n")
        run = read_run_file(tmp_path / "c.csv")
    np.testing.assert_allclose(run.time, t, atol=1e-6)
    _check(run, truth_run)
    assert f"clock time stamps{' with a date' if form in ('iso', 'dated_blank') else ''} (first" in run.meta["time_from"]
    assert ("midnight rollover at line 27: 24 h added" in run.meta["notes"]) == (form == "midnight")


@pytest.mark.parametrize("form", ["char", "cellstr_dated", "midnight"])
def test_clock_time_stored_as_text_in_a_mat_file(truth_run, tmp_path, form):
    """datestr()'s char matrix or a cell array of stamps as a .mat file's time: read as seconds from
    the first sample and said, as in a CSV file (they were refused as 'not a numeric vector')."""
    t, q, th = _table(truth_run)
    start = 86400 - 0.5 if form == "midnight" else 12 * 3600 + 34 * 60 + 56.02
    stamps = [_clock(start + a) for a in t]
    if form == "cellstr_dated":
        stamps = np.array([f"2026-11-26 {s}" for s in stamps], dtype=object)  # saved as a cell array
    savemat(tmp_path / "c.mat", {"time": stamps if form == "cellstr_dated" else np.array(stamps), "q": q, "theta": th})
    run = read_run_file(tmp_path / "c.mat", {"channels": {"q": "q", "theta": "theta"},
                                             "units": {"q": "deg/s", "theta": "deg"}})
    np.testing.assert_allclose(run.time, t, atol=1e-6)
    _check(run, truth_run)
    assert f"clock time stamps{' with a date' if form == 'cellstr_dated' else ''} (first" in run.meta["time_from"]
    assert ("midnight rollover at sample 26: 24 h added" in run.meta["notes"]) == (form == "midnight")


def test_text_time_in_a_mat_file_that_is_no_clock_is_refused_naming_the_sample(tmp_path):
    savemat(tmp_path / "x.mat", {"t": np.array(["12:00:00.00", "12:00:00.02", "noon"]), "q": np.arange(3.0)})
    with pytest.raises(RunError, match=r"time variable 't' is text but sample 3 \('noon'\) is no clock stamp"):
        read_run_file(tmp_path / "x.mat", {"channels": {"q": "q"}})


def test_clock_stamps_mixed_with_numbers_are_refused(tmp_path):
    (tmp_path / "mix.csv").write_text("time,q\n12:00:00.00,1\n12:00:00.02,2\n0.04,3\n")
    with pytest.raises(RunError, match="mixes clock stamps"):
        read_run_file(tmp_path / "mix.csv")


def test_unix_time_stamps_are_counted_from_the_first_and_said(truth_run, tmp_path, capsys):
    """1.7e9 s holds steps only to 2.4e-7 s in double precision: read from the first stamp, said,
    and the window counts from it too."""
    t, q, th = _table(truth_run)
    rows = "\n".join(f"{1.7e9 + a:.6f},{b:.9f},{c:.9f}" for a, b, c in zip(t, q, th))
    (tmp_path / "unix.csv").write_text("time,q [deg/s],theta [deg]\n" + rows + "\n")
    run = read_run_file(tmp_path / "unix.csv")
    _check(run, truth_run)
    np.testing.assert_allclose(run.time, t - t[0], atol=1e-9)
    assert "counted from the first stamp (1700000000" in run.meta["time_origin"]
    assert "counted from the first stamp" in capsys.readouterr().err
    assert provenance([run])["runs"][0]["time_origin"] == run.meta["time_origin"]  # and in the report's record
