"""Real-data ingest: units to SI, derived channels, time jitter and gaps, MATLAB v5 and v7.3 files.

Every test writes a run simulated from a known truth in the form real data arrives (degrees,
feet, knots, g, a left and a right surface, a jittered or gapped clock, a .mat file) and checks
that what is read back gives the estimates the plain SI run gives.
"""
import json
import math

import h5py
import numpy as np
import pytest
from scipy.io import savemat

from identify import LS, ML, LinearModel, RunError, read_run, read_runs, simulate_run
from identify.data.ingest import evaluate
from identify.data.io import load_channel_map, read_run_file, read_run_files
from identify.data.matfile import read_mat, read_mat_runs
from identify.data.units import canonical, looks_like_degrees, parse_units_spec, to_si

from tests.helpers import one_error_line, run_cli
from tests.identify.refine.test_refine import PROFILE as PITCH


def identify_cli(capsys, *args):
    """``identify`` run in-process (its main function): exit status, stdout, stderr lines."""
    from identify.cli import main

    capsys.readouterr()
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, [line for line in out.err.splitlines() if line.strip()]

PROFILE = PITCH  # u, q, theta driven by an elevator eta
DT, N = 0.02, 801
CHANNELS = ["eta", "u", "q", "theta", "u_dot", "q_dot", "theta_dot"]
# the units a flight-test file uses, with their SI factors written out independently of identify.units
FOREIGN = {"eta": ("deg", math.pi / 180), "u": ("ft/s", 0.3048), "q": ("deg/s", math.pi / 180),
           "theta": ("deg", math.pi / 180), "u_dot": ("g", 9.80665), "q_dot": ("deg/s^2", math.pi / 180),
           "theta_dot": ("deg/s", math.pi / 180)}


@pytest.fixture(scope="module")
def truth_run():
    """A 16 s run of the pitch model with three-level steps on eta (up to 5 deg) and 2 % noise."""
    rng = np.random.default_rng(3)
    u = np.repeat(rng.choice([-1.0, 0.0, 1.0], size=N // 25 + 1), 25)[:N] * 0.08
    u[:25] = 0.0
    return simulate_run(LinearModel(PROFILE), np.arange(N) * DT, u[:, None], noise_fraction=0.02, seed=4)


@pytest.fixture(scope="module")
def rad_estimates(truth_run, tmp_path_factory):
    path = truth_run.to_csv(tmp_path_factory.mktemp("rad") / "rad.csv", CHANNELS)
    return LS(PROFILE).fit([read_run(path)]).result_


def foreign_columns(run, names=CHANNELS):
    """The run's channels in the FOREIGN units: {name: values}."""
    return {n: run[n] / FOREIGN[n][1] for n in names}


def write_csv(path, time, columns, header_units=None, meta_units=None, bom=False):
    head = ""
    if meta_units:
        head += "# units: " + ", ".join(f"{n}={u}" for n, u in meta_units.items()) + "\n"
    names = ["time"] + [f"{n} [{header_units[n]}]" if header_units and n in header_units else n for n in columns]
    body = np.column_stack([time] + list(columns.values()))
    text = head + ",".join(names) + "\n" + "\n".join(",".join(f"{v:.15g}" for v in row) for row in body) + "\n"
    path.write_bytes(("\ufeff" if bom else "").encode() + text.encode())
    return path


def assert_same_estimates(result, reference, rtol=1e-9):
    np.testing.assert_allclose(result.theta, reference.theta, rtol=rtol)
    np.testing.assert_allclose(result.std, reference.std, rtol=max(rtol, 1e-9))


# -- the unit table -----------------------------------------------------------------------------------
@pytest.mark.parametrize("unit, value, si", [
    ("deg", 180.0, math.pi), ("DEG/S", 90.0, math.pi / 2), ("deg/sec", 1.0, math.pi / 180),
    ("°/s", 1.0, math.pi / 180), ("deg/s2", 1.0, math.pi / 180), ("rad/s²", 2.0, 2.0),
    ("ft", 1.0, 0.3048), ("ft/s", 10.0, 3.048), ("fps", 1.0, 0.3048), ("kt", 1.0, 1852 / 3600),
    ("knots", 100.0, 51.4444444444), ("km/h", 36.0, 10.0), ("in", 1.0, 0.0254), ("ft/s^2", 1.0, 0.3048),
    ("g", 1.0, 9.80665), ("%", 50.0, 0.5), ("-", 3.0, 3.0), ("ms", 20.0, 0.02), ("m/s", 4.0, 4.0),
])
def test_unit_table_converts_to_si(unit, value, si):
    assert to_si(np.array([value]), unit, "here")[0] == pytest.approx(si, rel=1e-10)


def test_unknown_unit_and_bad_units_line_name_the_channel():
    assert canonical("furlong") is None
    with pytest.raises(RunError, match=r"f.csv: channel 'q': unknown unit 'furlong/s'"):
        to_si(np.ones(2), "furlong/s", "f.csv: channel 'q'")
    assert parse_units_spec("q = deg/s, theta=deg", "f") == {"q": "deg/s", "theta": "deg"}
    with pytest.raises(RunError, match="units entry 'q deg/s' is not 'channel=unit'"):
        parse_units_spec("q deg/s", "f")


def test_degree_limits_are_the_physical_ones():
    # 10 deg of pitch read as radians is 10 rad: beyond half a turn; 1 rad of real pitch is not
    assert looks_like_degrees(np.array([0.0, 10.0]), "angle") == 10.0
    assert looks_like_degrees(np.array([-1.0, 1.0]), "angle") is None
    # a body rate of 30 deg/s read as rad/s is nearly 5 turns a second; 3 rad/s is a fast roll
    assert looks_like_degrees(np.array([30.0]), "angular rate") == 30.0
    assert looks_like_degrees(np.array([3.0]), "angular rate") is None
    assert looks_like_degrees(np.array([100.0]), "speed") is None
    # a control deflection of 2 deg read as radians is 115 deg: no surface or blade pitch goes there
    assert looks_like_degrees(np.array([2.0]), "control angle") == 2.0
    assert looks_like_degrees(np.array([2.0]), "angle") is None


# -- units in the file: same estimates as SI -------------------------------------------------------
@pytest.mark.parametrize("style", ["metadata", "header", "header-parentheses-bom"])
def test_degrees_with_declared_units_give_the_radian_estimates(truth_run, rad_estimates, tmp_path, style):
    cols = foreign_columns(truth_run)
    units = {n: FOREIGN[n][0] for n in CHANNELS}
    path = tmp_path / "deg.csv"
    if style == "metadata":
        write_csv(path, truth_run.time, cols, meta_units=units)
    elif style == "header":
        write_csv(path, truth_run.time, cols, header_units=units)
    else:
        write_csv(path, truth_run.time, cols, header_units=units, bom=True)
        path.write_text(path.read_text(encoding="utf-8-sig").replace("[", "(").replace("]", ")"),
                        encoding="utf-8-sig")
    run = read_run(path, require=PROFILE.channels, profile=PROFILE)
    assert "units" not in run.meta  # converted: writing the run again must not convert twice
    assert "theta from deg" in run.meta["converted_to_si"]
    np.testing.assert_allclose(run["theta"], truth_run["theta"], rtol=1e-12, atol=1e-15)
    assert_same_estimates(LS(PROFILE).fit([run]).result_, rad_estimates)
    # written back (SI now) and read again: unchanged
    again = read_run(run.to_csv(tmp_path / "again.csv"))
    np.testing.assert_allclose(again["u_dot"], run["u_dot"], rtol=1e-14)


def test_time_in_milliseconds(truth_run, tmp_path):
    path = write_csv(tmp_path / "ms.csv", truth_run.time * 1000, {"q": truth_run["q"]}, header_units={})
    path.write_text(path.read_text().replace("time,", "time [ms],", 1))
    assert read_run(path).dt == pytest.approx(DT)


def test_undeclared_degrees_warn_on_stderr_and_in_metadata(truth_run, tmp_path, capsys):
    cols = foreign_columns(truth_run)
    path = write_csv(tmp_path / "silent_deg.csv", truth_run.time, cols)
    run = read_run(path, profile=PROFILE)
    err = capsys.readouterr().err
    for name in ("eta", "q", "theta", "q_dot"):
        assert f"channel '{name}' (no unit declared; the profile's unit is SI)" in run.meta["warnings"]
        assert f"warning: {path}: channel '{name}'" in err
    assert "looks like deg; declare its unit ('# units: theta=deg'" in err
    assert "looks like deg/s; declare its unit ('# units: q=deg/s'" in err  # a rate: deg/s, not deg
    # u in ft/s and u_dot in g are not angles: no warning for them
    assert "channel 'u'" not in err and "channel 'u_dot'" not in err
    # declared rad but holding degrees: also a warning
    path2 = write_csv(tmp_path / "declared_rad.csv", truth_run.time, {"theta": cols["theta"]},
                      header_units={"theta": "rad"})
    assert "declared rad" in read_run(path2).meta["warnings"]
    # an elevator of at most 2 deg read as radians: beyond any control deflection
    small = {"eta": cols["eta"] * 2 / np.max(np.abs(cols["eta"]))}
    run3 = read_run(write_csv(tmp_path / "small_eta.csv", truth_run.time, small), profile=PROFILE)
    assert "beyond pi/2 rad (90 deg) for a control deflection" in run3.meta["warnings"]
    capsys.readouterr()
    # SI data: no warning
    read_run(truth_run.to_csv(tmp_path / "si.csv", CHANNELS), profile=PROFILE)
    assert "warning" not in capsys.readouterr().err


def test_spreadsheet_and_logger_layouts(truth_run, tmp_path):
    q, theta = truth_run["q"][:50], truth_run["theta"][:50]
    t = truth_run.time[:50]
    blank = "\n".join(" ".join(f"{v:.15g}" for v in row) for row in zip(t, np.degrees(q), theta))
    # blank-delimited, a unit in brackets with a blank inside it
    (tmp_path / "blank.txt").write_text("Time   q [deg/s]  theta\n" + blank + "\n")
    run = read_run(tmp_path / "blank.txt")
    np.testing.assert_allclose(run["q"], q, rtol=1e-12, atol=1e-15)
    # quoted cells, a trailing delimiter, semicolons
    text = '"time";"q";"theta";\n' + "\n".join(f'"{a:.15g}";{b:.15g};{c:.15g};' for a, b, c in zip(t, q, theta))
    (tmp_path / "sheet.csv").write_text(text + "\n")
    run = read_run(tmp_path / "sheet.csv")
    assert set(run.channels) == {"q", "theta"}
    np.testing.assert_allclose(run["theta"], theta, rtol=1e-12, atol=1e-15)


def test_missing_values_in_an_unused_column_are_left_out_and_said(truth_run, tmp_path, capsys):
    cols = {n: truth_run[n] for n in ("eta", "u", "q", "theta")}
    cols["spare"] = np.full(N, np.nan)
    path = write_csv(tmp_path / "spare.csv", truth_run.time, cols)
    path.write_text(path.read_text().replace(",nan\n", ",\n"))  # empty cells, as loggers write them
    run = read_run(path, profile=PROFILE)
    assert "spare" not in run.channels
    assert f"{path}: channel 'spare' has {N} missing or non-finite value(s): left out" in capsys.readouterr().err
    # without a profile, or in a channel the profile uses: one clear line
    with pytest.raises(RunError, match=r"spare.csv: line 2, channel 'spare': nan value"):
        read_run(path)
    text = path.read_text().splitlines()
    text[5] = ",".join(text[5].split(",")[:3] + ["", text[5].split(",")[4], ""])
    path.write_text("\n".join(text) + "\n")
    with pytest.raises(RunError, match=r"spare.csv: line 6, channel 'q': nan value \(1 missing or non-finite"):
        read_run(path, profile=PROFILE)


def test_unit_of_another_quantity_than_the_profile_is_an_error(truth_run, tmp_path):
    path = write_csv(tmp_path / "odd.csv", truth_run.time, {"q": truth_run["q"]}, header_units={"q": "ft/s"})
    with pytest.raises(RunError, match=r"odd.csv: channel 'q' is declared in ft/s \(speed\) but the profile "
                                       r"expects angular rate \(a unit of the wrong kind"):
        read_run(path, profile=PROFILE)


def test_conflicting_and_unknown_units_are_one_clear_line(truth_run, tmp_path):
    path = write_csv(tmp_path / "c.csv", truth_run.time, {"q": truth_run["q"]}, header_units={"q": "deg/s"},
                     meta_units={"q": "rad/s"})
    with pytest.raises(RunError, match=r"c.csv: channel 'q': unit declared as both 'deg/s' and 'rad/s'"):
        read_run(path)
    path = write_csv(tmp_path / "u.csv", truth_run.time, {"q": truth_run["q"]}, header_units={"q": "deg/min"})
    with pytest.raises(RunError, match=r"u.csv: line 1, column 'q \[deg/min\]': unknown unit 'deg/min'"):
        read_run(path)


# -- derived channels ------------------------------------------------------------------------------
def test_derived_channel_from_left_and_right_surfaces(truth_run, rad_estimates, tmp_path):
    cols = foreign_columns(truth_run)
    eta = cols.pop("eta")
    # the elevator as the mean of two surfaces with a symmetric rigging offset, in degrees
    cols = {"der": eta + 1.5, "del": -eta + 1.5, **cols}
    units = {n: FOREIGN[n][0] for n in CHANNELS if n != "eta"} | {"der": "deg", "del": "deg"}
    path = write_csv(tmp_path / "surfaces.csv", truth_run.time, cols, meta_units=units)
    cmap = {"channels": {"eta": "(der - del) / 2"}}
    run = read_run(path, channel_map=cmap, profile=PROFILE)
    np.testing.assert_allclose(run["eta"], truth_run["eta"], rtol=1e-12, atol=1e-15)
    assert run.meta["derived"] == "eta = (der - del) / 2"
    assert_same_estimates(LS(PROFILE).fit([run]).result_, rad_estimates)
    # the unit may be declared on the derived channel instead of its operands
    path2 = write_csv(tmp_path / "raw_surfaces.csv", truth_run.time, {"der": eta, "del": -eta})
    run2 = read_run(path2, channel_map={"channels": {"eta": "0.5*(der - del)"}, "units": {"eta": "deg"}})
    np.testing.assert_allclose(run2["eta"], truth_run["eta"], rtol=1e-12, atol=1e-15)
    # ...but not on both
    with pytest.raises(RunError, match="declared both for 'eta' .* and for its operand"):
        read_run(path, channel_map={"channels": {"eta": "(der - del)/2"}, "units": {"eta": "deg"}})


@pytest.mark.parametrize("expr, needle", [
    ("__import__('os').system('true')", "is not allowed"),
    ("abs(a)", "'abs(a)' is not allowed"),
    ("a ** 2", "'a ** 2' is not allowed"),
    ("a if b else 1", "not an arithmetic expression"),  # keywords are names here: not a valid sum
    ("a +", "not an arithmetic expression"),
    ("a + c", "no column or channel 'c'"),
    ("(1).real", "is not allowed"),
    ("a[0]", "'a[0]' is not allowed"),
])
def test_expression_evaluator_refuses_anything_but_arithmetic(expr, needle):
    data = {"a": np.array([1.0, 2.0]), "b": np.array([3.0, 4.0])}

    def lookup(name):
        if name not in data:
            raise RunError(f"where: no column or channel '{name}'")
        return data[name]

    with pytest.raises(RunError, match="where") as err:
        evaluate(expr, lookup, "where")
    assert needle in str(err.value)
    np.testing.assert_allclose(evaluate("-(a - b) / 2 * 3 + 1.5e0", lookup, "where"), [4.5, 4.5])


def test_derived_channel_that_refers_to_itself_or_divides_by_zero(truth_run, tmp_path):
    path = write_csv(tmp_path / "d.csv", truth_run.time, {"a": truth_run["q"], "z": 0 * truth_run["q"]})
    with pytest.raises(RunError, match="refers to itself"):
        read_run(path, channel_map={"channels": {"x": "y + 1", "y": "x * 2"}})
    with pytest.raises(RunError, match=r"line 2, channel 'x': (nan|inf) value"):
        read_run(path, channel_map={"channels": {"x": "a / z"}})


# -- time jitter and gaps --------------------------------------------------------------------------
def test_small_time_jitter_is_resampled_and_reported(truth_run, rad_estimates, tmp_path, capsys):
    rng = np.random.default_rng(7)
    jitter = rng.uniform(-1e-5, 1e-5, N)  # the +-1e-5 s of a recorded clock, 0.05 % of the step
    path = write_csv(tmp_path / "jitter.csv", truth_run.time + jitter, {n: truth_run[n] for n in CHANNELS})
    run = read_run(path)
    # off the grid through the first and last stamps: up to twice the clock's 1e-5 s, 0.1 % of a step
    assert 0 < float(run.meta["time_jitter"]) <= 0.001
    assert "resampled onto the uniform grid by linear interpolation" in run.meta["resampled"]
    assert "note:" in capsys.readouterr().err
    assert run.dt == pytest.approx(DT, rel=1e-5)
    # the resampling moves each value by at most slope x 1e-5 s: the estimates stay within 2 % of
    # their standard errors of the clean run's
    est = LS(PROFILE).fit([run]).result_
    assert np.all(np.abs(est.theta - rad_estimates.theta) < 0.02 * rad_estimates.std), \
        (est.theta - rad_estimates.theta) / rad_estimates.std


def test_large_irregularity_is_one_clear_error(truth_run, tmp_path):
    t = truth_run.time.copy()
    t[100] += 0.2 * DT  # 20 % of a step off, not a gap
    path = write_csv(tmp_path / "irregular.csv", t, {"q": truth_run["q"]})
    with pytest.raises(RunError, match=r"irregular.csv: line 102, channel 'time': time stamp 2.004 s is 20% of a "
                                       r"step off the uniform 0.02 s grid \(irregular sampling"):
        read_run(path)


def test_time_gap_splits_the_file_into_runs(truth_run, rad_estimates, tmp_path, capsys):
    keep = np.ones(N, bool)
    keep[300:340] = False  # 0.8 s of lost telemetry
    path = write_csv(tmp_path / "gap.csv", truth_run.time[keep], {n: truth_run[n][keep] for n in CHANNELS})
    runs = read_runs([path], require=PROFILE.channels)
    assert [len(r) for r in runs] == [300, N - 340]
    assert runs[0].source == f"{path} [segment 1/2]"
    assert runs[1].meta["segment"] == "2 of 2: t = 6.8..16 s"
    assert "1 time gap(s) longer than 1.5 x the 0.02 s step at line 302 (5.98 -> 6.8 s)" in runs[0].meta["time_gaps"]
    assert "split the file into 2 runs" in capsys.readouterr().err
    # the two segments together estimate what the whole run does, within the standard errors
    est = LS(PROFILE).fit(runs).result_
    assert np.all(np.abs(est.theta - rad_estimates.theta) < 2 * est.std)
    # a reader of one run says so in one line
    with pytest.raises(RunError, match=r"gap.csv: 1 time gap.*split the file into 2 runs; read it with read_runs"):
        read_run(path)


def test_lone_samples_between_gaps_are_dropped_and_said(tmp_path):
    t = np.r_[np.arange(10) * 0.1, 2.0, np.arange(10) * 0.1 + 3.0]
    path = write_csv(tmp_path / "lone.csv", t, {"q": np.sin(t)})
    runs = read_runs([path])
    assert [len(r) for r in runs] == [10, 10]
    assert "1 lone sample(s) between gaps dropped" in runs[0].meta["time_gaps"]


# -- MATLAB files ----------------------------------------------------------------------------------
def save_mat73(path, variables):
    """A MATLAB v7.3 file as MATLAB writes it: HDF5 after a 512-byte header, arrays transposed
    (column-major), each dataset tagged with its MATLAB class; a dict becomes a struct."""
    def put(group, name, value):
        if isinstance(value, dict):
            sub = group.create_group(name)
            sub.attrs["MATLAB_class"] = np.bytes_("struct")
            for k, v in value.items():
                put(sub, k, v)
            return
        a = np.asarray(value, dtype=float)
        a = a[:, None] if a.ndim == 1 else a  # a MATLAB column vector, N x 1
        ds = group.create_dataset(name, data=a.T)
        ds.attrs["MATLAB_class"] = np.bytes_("double")

    with h5py.File(path, "w", userblock_size=512) as f:
        for k, v in variables.items():
            put(f, k, v)
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Nov 23 04:00:00 2026 HDF5 schema 1.00 ."
    with open(path, "r+b") as fh:
        fh.write(header.ljust(116, b" ") + b"\0" * 8 + b"\x00\x02" + b"IM")
    return path


@pytest.mark.parametrize("version", ["v5", "v7.3"])
def test_mat_data_matrix_in_flight_test_units(truth_run, rad_estimates, tmp_path, version):
    cols = foreign_columns(truth_run)
    # the elevator as two surface columns (right, left), the rest one column each, time first
    Z = np.column_stack([truth_run.time, cols["eta"], -cols["eta"]] + [cols[n] for n in CHANNELS[1:]])
    path = tmp_path / f"flight_{version}.mat"
    savemat(path, {"Z": Z}) if version == "v5" else save_mat73(path, {"Z": Z})
    channels = {"er": 1, "el": 2, "eta": "(er - el)/2", **{n: j + 3 for j, n in enumerate(CHANNELS[1:])}}
    units = {n: FOREIGN[n][0] for n in CHANNELS[1:]} | {"er": "deg", "el": "deg"}
    cmap = load_channel_map(json.dumps({"channels": channels, "time": 0, "units": units}))
    run = read_run_file(path, cmap, profile=PROFILE)
    np.testing.assert_allclose(run["eta"], truth_run["eta"], rtol=1e-12, atol=1e-15)
    assert run.meta["source_format"] == f"MATLAB .mat {version}"
    assert_same_estimates(LS(PROFILE).fit([run]).result_, rad_estimates)


def test_mat73_named_variables_struct_fields_and_derived_channel(truth_run, rad_estimates, tmp_path):
    cols = foreign_columns(truth_run)
    eta = cols.pop("eta")
    flight = {"t": truth_run.time, "dur": eta, "dul": -eta, **{k.upper(): v for k, v in cols.items()}}
    path = save_mat73(tmp_path / "named73.mat", {"flight": flight, "note_len": np.ones(3)})
    channels = {n: f"flight.{n.upper()}" for n in CHANNELS if n != "eta"}
    channels["eta"] = "(flight.dur - flight.dul) / 2"
    units = {n: FOREIGN[n][0] for n in CHANNELS}
    runs = read_mat_runs(path, channels, time="flight.t", units=units, profile=PROFILE)
    assert len(runs) == 1
    assert_same_estimates(LS(PROFILE).fit(runs).result_, rad_estimates)
    # ML on the v7.3 run and on the SI run: the same estimates
    si = ML(PROFILE).fit([truth_run]).result_
    np.testing.assert_allclose(ML(PROFILE).fit(runs).result_.theta, si.theta, rtol=1e-6)


def test_mat_file_with_gap_and_v5_struct(truth_run, tmp_path):
    keep = np.ones(N, bool)
    keep[500:520] = False
    s = {"time": truth_run.time[keep], "q": truth_run["q"][keep], "theta": truth_run["theta"][keep]}
    ragged = np.empty(2, dtype=object)
    ragged[:] = [np.ones(3), np.ones(5)]  # a cell array: no channel, and no crash
    savemat(tmp_path / "gap5.mat", {"rec": s, "cells": ragged})
    runs = read_run_files([tmp_path / "gap5.mat"], {"channels": {"q": "rec.q", "theta": "rec.theta"},
                                                   "time": "rec.time"})
    assert [len(r) for r in runs] == [500, N - 520]
    assert len(read_mat_runs(tmp_path / "gap5.mat")) == 2  # no map: every vector (struct fields too)
    with pytest.raises(RunError, match="read it with read_mat_runs"):
        read_mat(tmp_path / "gap5.mat", {"q": "rec.q"}, time="rec.time")


def test_broken_v73_file_is_one_clear_line(tmp_path):
    path = save_mat73(tmp_path / "broken.mat", {"q": np.ones(10)})
    data = path.read_bytes()
    path.write_bytes(data[:600])  # truncated
    with pytest.raises(RunError, match="broken.mat: not a readable MATLAB"):
        read_mat(path)


def test_channel_map_units_are_validated():
    with pytest.raises(RunError, match="channel map: units of 'q': unknown unit 'degs'"):
        load_channel_map('{"channels": {"q": 0}, "units": {"q": "degs"}}')
    with pytest.raises(RunError, match="'units' must be an object"):
        load_channel_map('{"channels": {"q": 0}, "units": ["deg"]}')


# -- the command lines -----------------------------------------------------------------------------
def test_cli_estimate_same_result_from_degree_csv_and_v73_with_gap(truth_run, tmp_path, capsys):
    prof = PROFILE.save(tmp_path / "pitch.toml")
    rad = truth_run.to_csv(tmp_path / "rad.csv", CHANNELS)
    deg = write_csv(tmp_path / "deg.csv", truth_run.time, foreign_columns(truth_run),
                    header_units={n: FOREIGN[n][0] for n in CHANNELS})
    out = {}
    for name, path in (("rad", rad), ("deg", deg)):
        code, _, err = identify_cli(capsys, "estimate", "--profile", prof, "--method", "ls", path, "--out",
                                    tmp_path / name)
        # every conversion said, one line per converted channel (the walkthrough's promise), nothing else
        said = {line.split("'")[1]: line for line in err}
        assert code == 0 and sorted(said) == (sorted(FOREIGN) if name == "deg" else []), err
        assert all(f"converted from {FOREIGN[n][0]} to " in line for n, line in said.items()), err
        out[name] = json.loads((tmp_path / name / "result.json").read_text())
        prov = out[name]["info"]["provenance"]["runs"][0]
        assert (prov.get("units_declared", "").count("=") == len(FOREIGN)) == (name == "deg")  # recorded
    for name, p in out["rad"]["parameters"].items():
        assert out["deg"]["parameters"][name]["value"] == pytest.approx(p["value"], rel=1e-9)
    # a v7.3 file with a gap: two runs, exit 0, the split said
    keep = np.ones(N, bool)
    keep[400:430] = False
    path = save_mat73(tmp_path / "gap73.mat", {"t": truth_run.time[keep],
                                                **{n: truth_run[n][keep] for n in CHANNELS}})
    code, _, err = identify_cli(capsys, "estimate", "--profile", prof, "--method", "ls", path, "--out",
                                tmp_path / "m", "--t-start", "0", "--t-end", "30")
    assert code == 0, err
    assert "split the file into 2 runs" in err[0]
    assert len(json.loads((tmp_path / "m" / "result.json").read_text())["runs"]) == 2
    # a window holding only the first segment: the second is left out, and said
    code, _, err = identify_cli(capsys, "estimate", "--profile", prof, "--method", "ls", path, "--out",
                                tmp_path / "m1", "--t-end", "7.5")
    assert code == 0 and "[segment 2/2] lies outside --t-start/--t-end: not used" in err[-1], err


def test_cli_refine_reads_v73_mat(truth_run, tmp_path, capsys):
    prof = PROFILE.save(tmp_path / "pitch.toml")
    path = save_mat73(tmp_path / "fit73.mat", {"t": truth_run.time, **{n: truth_run[n] for n in CHANNELS}})
    code, _, err = identify_cli(capsys, "refine", "--profile", prof, path, "--kinds", "bias", "--max-steps", "1",
                                "--no-zero-shifts", "--out", tmp_path / "out")
    assert code == 0, err
    assert "fit73.mat" in (tmp_path / "out" / "refine.json").read_text()


def bad_input(truth_run, tmp_path, case):
    """A bad file (and extra options) for ``case``."""
    cols = {n: truth_run[n][:40] for n in ("eta", "u", "q", "theta")}
    t = truth_run.time[:40].copy()
    path = tmp_path / "bad.csv"
    if case == "unknown unit":
        write_csv(path, t, cols, header_units={"q": "furlong"})
    elif case == "irregular":
        t[10] += 0.3 * DT
        write_csv(path, t, cols)
    elif case == "bad expression":
        write_csv(path, t, cols)
        return path, ["--channel-map", '{"channels": {"eta": "q ** 2"}}']
    else:
        path = save_mat73(tmp_path / "bad.mat", {"t": t, **cols})
        path.write_bytes(path.read_bytes()[:700])
    return path, []


@pytest.mark.parametrize("command", ["estimate", "refine"])
@pytest.mark.parametrize("case, needles", [
    ("unknown unit", ["bad.csv", "column 'q [furlong]'", "unknown unit 'furlong'"]),
    ("irregular", ["bad.csv", "line 12, channel 'time'", "irregular sampling"]),
    ("bad expression", ["channel map", "'eta' = 'q ** 2'", "not allowed"]),
    ("broken v7.3", ["bad.mat", "not a readable MATLAB"]),
])
def test_cli_bad_input_is_one_line_and_status_2(truth_run, tmp_path, capsys, command, case, needles):
    prof = PROFILE.save(tmp_path / "pitch.toml")
    path, extra = bad_input(truth_run, tmp_path, case)
    code, _, err = identify_cli(capsys, command, "--profile", prof, path, "--out", tmp_path / "o", *extra)
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith("identify: error: ") and all(n in err[0] for n in needles), err


def test_cli_broken_v73_in_a_subprocess_has_no_traceback(truth_run, tmp_path):
    prof = PROFILE.save(tmp_path / "pitch.toml")
    path, _ = bad_input(truth_run, tmp_path, "broken v7.3")
    proc = run_cli("identify", "refine", "--profile", prof, path, "--out", tmp_path / "o")
    one_error_line(proc, "bad.mat", "not a readable MATLAB v7.3 (HDF5) file")
