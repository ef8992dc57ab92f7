"""Real flight data without surprises (issue #21): each way a file could give a wrong result
silently is either read right or refused in one line that says what the file holds."""
import json

import numpy as np
import pytest
from scipy.io import savemat

from identify import LS, RunError, read_run
from identify.data.ingest import ReadOptions
from identify.data.io import read_file_runs, read_run_file, read_run_files
from identify.data.preprocess import processing_steps, remove_trim
from identify.data.units import canonical, to_si
from tests.identify.data.test_ingest import CHANNELS, DT, PROFILE, identify_cli, truth_run  # noqa: F401

DEG = np.pi / 180


def _asc(path, run, names=CHANNELS, time=True):
    """A whitespace text file of numbers, no header (as textbook data sets come)."""
    cols = ([run.time] if time else []) + [run[n] for n in names]
    np.savetxt(path, np.column_stack(cols), fmt="%.10g")
    return path


def test_headerless_text_is_refused_saying_so_or_read_with_declared_columns(truth_run, tmp_path):
    path = _asc(tmp_path / "flight.asc", truth_run)
    with pytest.raises(RunError, match=r"flight.asc: line 1: the file has no header \(the first row is numbers"):
        read_run_file(path, {"channels": {"q": 2}})
    cmap = {"columns": ["time", *CHANNELS]}
    run = read_run_file(path, cmap)
    assert len(run) == len(truth_run)  # the first sample is not lost to a header
    assert np.allclose(run["q"], truth_run["q"]) and np.allclose(run.time, truth_run.time)
    # no time column: the map's dt gives the time
    path2 = _asc(tmp_path / "notime.asc", truth_run, time=False)
    run2 = read_run_file(path2, {"columns": CHANNELS, "dt": DT})
    assert run2.dt == pytest.approx(DT) and len(run2) == len(truth_run)
    assert "dt = 0.02 s" in run2.meta["time_from"]
    with pytest.raises(RunError, match=r"dt 0.05 s disagrees with the time column"):
        read_run_file(path, {"columns": ["time", *CHANNELS], "dt": 0.05})


def test_one_based_column_numbers_are_refused_unless_declared(truth_run, tmp_path):
    names = ["time", *CHANNELS]
    savemat(tmp_path / "m.mat", {"fdata": np.column_stack([truth_run[n] for n in names])})
    one_based = {"time": 1, "channels": {n: i + 1 for i, n in enumerate(names) if n != "time"}}
    with pytest.raises(RunError, match=r"look 1-based \(MATLAB\).*declare \"index_base\": 1"):
        read_run_file(tmp_path / "m.mat", one_based)
    run = read_run_file(tmp_path / "m.mat", dict(one_based, index_base=1))
    assert np.allclose(run["q"], truth_run["q"]) and np.allclose(run["theta"], truth_run["theta"])


@pytest.mark.parametrize("suffix", [".csv", ".mat"])
def test_degrees_found_by_kinematics_with_the_rates_unit_and_the_fix_for_the_file_type(truth_run, tmp_path, suffix):
    small = {n: truth_run[n] for n in CHANNELS}
    small["q"] = truth_run["q"] * (3.8 * DEG / np.max(np.abs(truth_run["q"]))) / DEG  # peak 3.8, in deg/s
    small["theta"] = np.cumsum(np.r_[0, 0.5 * (truth_run["q"][1:] + truth_run["q"][:-1])]) * DT
    small["theta"] *= 3.8 * DEG / np.max(np.abs(truth_run["q"]))  # consistent with q in rad, rad
    path = tmp_path / f"small{suffix}"
    if suffix == ".csv":
        from identify.data.runs import Run
        Run(truth_run.time, small).to_csv(path)
        fix = "'# units: q=deg/s'"
    else:
        savemat(path, {"t": truth_run.time, **small})
        fix = '"units": {"q": "deg/s"}'
    # the peak (3.8 "rad/s") is within what radians reach: only kinematics can tell
    warnings = read_run_file(path, profile=PROFILE).meta["warnings"]
    assert "channel 'q' looks like deg/s" in warnings and fix in warnings
    assert ("'# units" in warnings) == (suffix == ".csv")


def test_a_data_matrix_found_alone_or_by_the_files_stem_so_one_map_reads_several_files(truth_run, tmp_path):
    names = ["time", *CHANNELS]
    cols = np.column_stack([truth_run[n] for n in names])
    for stem in ("da3211", "de3211"):
        savemat(tmp_path / f"{stem}.mat", {stem: cols, "note": np.array([[1.0]])})
    cmap = {"time": 0, "channels": {n: i for i, n in enumerate(names) if n != "time"}}
    runs = read_run_files([tmp_path / "da3211.mat", tmp_path / "de3211.mat"], cmap)  # the only matrix
    assert len(runs) == 2 and runs[0].meta["matrix"] == "da3211" and runs[1].meta["matrix"] == "de3211"
    runs = read_run_files([tmp_path / "da3211.mat", tmp_path / "de3211.mat"], dict(cmap, matrix="{stem}"))
    assert np.allclose(runs[1]["q"], truth_run["q"])
    savemat(tmp_path / "two.mat", {"a": cols, "b": cols})
    with pytest.raises(RunError, match=r"several data matrices \(a, b\).*\{stem\}"):
        read_run_file(tmp_path / "two.mat", cmap)


def test_trim_removal_first_second_mean_or_none_recorded(truth_run, tmp_path, capsys):
    offset = truth_run.with_channels({n: truth_run[n] + 0.3 for n in CHANNELS})
    trimmed = remove_trim(offset, "first:0.4s")
    assert np.allclose(trimmed["u"][:20], truth_run["u"][:20] - np.mean(truth_run["u"][:21]), atol=1e-12)
    (step,) = processing_steps(trimmed)
    assert step["how"] == "first:0.4s" and step["values"]["u"] == pytest.approx(0.3 + np.mean(truth_run["u"][:21]))
    assert abs(np.mean(remove_trim(offset, "mean")["q"])) < 1e-12
    path = offset.to_csv(tmp_path / "trim.csv", CHANNELS)
    prof = PROFILE.save(tmp_path / "p.toml")
    code, _, err = identify_cli(capsys, "estimate", "--profile", prof, "--method", "ls", path, "--out",
                                tmp_path / "o", "--trim", "first:0.5s")
    assert code == 0 and any("trim removed (first:0.5s)" in line for line in err)
    result = json.loads((tmp_path / "o" / "result.json").read_text())
    steps = result["info"]["provenance"]["runs"][0]["processing"]
    assert steps[-1]["step"] == "trim" and steps[-1]["how"] == "first:0.5s"
    code, _, err = identify_cli(capsys, "estimate", "--profile", prof, path, "--out", tmp_path / "x", "--trim", "last")
    assert code == 2 and "trim must be" in err[-1]


def test_nan_outside_the_window_cut_inside_refused_dropped_or_interpolated(truth_run, tmp_path):
    cols = {n: truth_run[n].copy() for n in CHANNELS}
    cols["u"][5] = np.nan  # t = 0.1 s
    cols["q"][400] = np.nan  # t = 8 s
    from identify.data.runs import Run
    path = Run(truth_run.time, cols).to_csv(tmp_path / "nan.csv")
    run = read_run_file(path, options=ReadOptions(t_start=1.0, t_end=7.0))  # neither inside
    assert run.time[0] == pytest.approx(1.0) and "cut to the window" in run.meta["missing_outside_window"]
    with pytest.raises(RunError, match=r"channel 'q': nan value .*--nan drop or --nan interpolate"):
        read_run_file(path, options=ReadOptions(t_start=1.0))
    dropped = read_file_runs(path, options=ReadOptions("drop", t_start=1.0))
    assert len(dropped) == 2 and "1 sample(s) with missing values dropped (line" in dropped[0].meta["dropped_samples"]
    # the gap the hole leaves is named by the file's lines, not by the positions after the cut
    assert "line 403 (7.98 -> 8.02 s)" in dropped[0].meta["time_gaps"], dropped[0].meta["time_gaps"]
    (filled,) = read_file_runs(path, options=ReadOptions("interpolate", t_start=1.0))
    assert len(filled) == len(truth_run) - 50 and "interpolated" in filled.meta["interpolated_samples"]
    assert filled["q"][350] == pytest.approx(0.5 * (truth_run["q"][399] + truth_run["q"][401]))


def test_field_units_and_a_unit_of_the_wrong_kind(truth_run, tmp_path):
    expect = {"rps": 1.0, "deg/s/s": DEG, "m/s/s": 1.0, "1/s": 1.0, "KTAS": 1852 / 3600, "lbs": 4.4482216152605,
              "psf": 4.4482216152605 / 0.3048 ** 2}
    for unit, factor in expect.items():
        assert canonical(unit) is not None, unit
        assert to_si(np.array([2.0]), unit, "x")[0] == pytest.approx(2 * factor), unit
    from identify.data.runs import Run
    path = Run(truth_run.time, {"q": truth_run["q"]}).to_csv(tmp_path / "k.csv")
    path.write_text(path.read_text().replace("time,q", "time,q [KTAS]"))
    with pytest.raises(RunError, match=r"declared in KTAS \(speed\) but the profile expects angular rate"):
        read_run_file(path, profile=PROFILE)


def test_struct_arrays_give_a_run_per_element_and_missing_names_list_the_file(truth_run, tmp_path):
    half = len(truth_run) // 2
    flight = np.empty((1, 2), dtype=[("t", object), ("q", object), ("theta", object)])
    for k, sl in enumerate((slice(0, half), slice(half, None))):
        flight[0, k] = (truth_run.time[sl], truth_run["q"][sl], truth_run["theta"][sl])
    savemat(tmp_path / "s.mat", {"flight": flight})
    runs = read_run_files([tmp_path / "s.mat"], {"time": "flight.t", "channels": {"q": "flight.q"}})
    assert len(runs) == 2 and np.allclose(runs[1]["q"], truth_run["q"][half:])
    assert runs[1].meta["struct_element"] == "flight(2)"
    with pytest.raises(RunError, match=r"no variable 'flight.r' in the file \(variables: .*flight.q"):
        read_run_files([tmp_path / "s.mat"], {"time": "flight.t", "channels": {"r": "flight.r"}})
    path = truth_run.to_csv(tmp_path / "c.csv", ["q"])
    with pytest.raises(RunError, match=r"no column 'pitch' \(columns: time, q\)"):
        read_run_file(path, {"channels": {"theta": "pitch"}})


def test_provenance_in_result_json(truth_run, tmp_path, capsys):
    import hashlib
    path = truth_run.to_csv(tmp_path / "p.csv", CHANNELS)
    code, _, _ = identify_cli(capsys, "estimate", "--profile", PROFILE.save(tmp_path / "p.toml"), "--method", "ls",
                              path, "--out", tmp_path / "o", "--channel-map", '{"channels": {"de": "eta"}}')
    assert code == 0
    prov = json.loads((tmp_path / "o" / "result.json").read_text())["info"]["provenance"]
    assert prov["tool"].startswith("pseudostep ")
    (r,) = prov["runs"]
    assert r["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    assert r["channel_map"] == {"channels": {"de": "eta"}} and r["samples"] == len(truth_run)
